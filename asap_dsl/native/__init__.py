"""The compiled environment step: each task's whole step as one numba function over the batch.

For an ``ode`` or ``map`` system the generated code (:mod:`.kernel`) integrates the dynamics
with the integrator's substeps, evaluates the regions and comparisons (:mod:`.exprs`, through the
expression compiler's own generator), runs the online monitors (:mod:`.monitors`), and computes
the reward, the end reasons, the observation and the info values; a black-box simulator steps in
Python and the rest is compiled around it. Each generated module is cached on disk by the hash
of its source (:mod:`.cache`): a second start loads machine code instead of compiling.
:class:`.core.NativeCore` runs it with the numpy core's episodes, sampler and random stream, so
both engines, given the same seed and actions, go through the same episodes with the same values.

``engine`` (``make_env``/``make_vec_env``, ``$ASAP_ENGINE``): ``"native"`` (the compiled step;
ValueError where it does not apply), ``"numpy"`` (the reference), ``"auto"`` (compiled where it
applies, else numpy; the default).
"""

from __future__ import annotations

import os

ENGINES = ("auto", "native", "numpy")


def resolve_engine(engine: str | None) -> str:
    """``engine`` checked (None: ``$ASAP_ENGINE``, else ``"auto"``)."""
    if engine is None:
        engine = os.environ.get("ASAP_ENGINE") or "auto"
    if engine not in ENGINES:
        raise ValueError(f"unknown engine {engine!r}; choose auto, native or numpy")
    return engine


def with_engine(core, engine: str | None = None):
    """The numpy core ``core`` stepped by ``engine`` (see the module docstring)."""
    engine = resolve_engine(engine)
    if engine == "numpy":
        return core
    from .core import native_core

    return native_core(core, require=engine == "native")


__all__ = ["ENGINES", "resolve_engine", "with_engine"]
