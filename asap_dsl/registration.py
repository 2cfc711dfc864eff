"""Gymnasium ids: ``asap/<spec>-<task>-v0`` for every task of the benchmark specs, and
:func:`register` for a user's own spec.

``import asap_dsl`` registers the benchmark ids without importing gymnasium (which takes some
150 ms): when gymnasium is loaded already they are registered at once, otherwise the moment it is
imported (a hook on its import, removed once it has run). The ids are found by reading the task
names from the spec files; a spec is loaded, and checked, only when its environment is made. So
all of these work::

    import asap_dsl, gymnasium
    gymnasium.make("asap/dc_motor-reach_avoid-v0")
    gymnasium.make("asap_dsl:asap/dc_motor-reach_avoid-v0")   # gymnasium imports asap_dsl itself
    # rl_zoo3 train --env asap/dc_motor-reach_avoid-v0 --gym-packages asap_dsl

(gymnasium 1.x has no entry-point plugins: ``--gym-packages`` or the ``asap_dsl:`` prefix is how
a tool that takes only an id gets them.)
"""

from __future__ import annotations

import os
import sys

# Nothing else at the top: `import asap_dsl` runs install() and must stay a few milliseconds
# (re, pathlib and typing are imported where they are used; annotations stay strings).

__all__ = ["NAMESPACE", "benchmark_ids", "register", "register_benchmarks", "specs_dir"]

NAMESPACE = "asap"
_ENTRY = "asap_dsl.env:_make_registered"


def specs_dir():
    """The benchmark specs: asap_dsl/specs in the wheel, specs/ in a source checkout."""
    from pathlib import Path

    here = Path(__file__).resolve().parent
    return here / "specs" if (here / "specs").is_dir() else here.parent / "specs"


def env_id(spec: str | os.PathLike, task: str) -> str:
    """``asap/<spec file's stem>-<task>-v0``."""
    from pathlib import Path

    return f"{NAMESPACE}/{Path(spec).stem}-{task}-v0"


def benchmark_ids(directory: str | os.PathLike | None = None) -> dict[str, tuple[str, str]]:
    """Each id of the benchmark specs (or of ``directory``'s) -> (spec path, task), from the task
    names in the files (comments aside), without parsing them."""
    import re
    from pathlib import Path

    pattern = re.compile(r"^[ \t]*task[ \t]+([A-Za-z_][A-Za-z0-9_]*)[ \t]*\{", re.M)
    d = Path(directory) if directory is not None else specs_dir()
    out: dict[str, tuple[str, str]] = {}
    for f in sorted(d.glob("*.asap")) if d.is_dir() else ():
        try:
            text = f.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError):
            continue
        text = re.sub(r"#[^\n]*", "", text)
        for task in pattern.findall(text):
            out[env_id(f, task)] = (str(f), task)
    return out


def _register_id(gid: str, path: str, task: str, kwargs: dict | None = None) -> None:
    import gymnasium as gym

    if gid not in gym.registry:
        gym.register(id=gid, entry_point=_ENTRY, kwargs={"path": path, "task": task, **(kwargs or {})},
                     max_episode_steps=None, disable_env_checker=True)


def register_benchmarks() -> list[str]:
    """Register the benchmark ids with gymnasium (importing it); the ids."""
    ids = benchmark_ids()
    for gid, (path, task) in ids.items():
        _register_id(gid, path, task)
    return list(ids)


def register(spec: str | os.PathLike, task: str | None = None, *, id: str | None = None,
             **env_kwargs: object) -> list[str]:
    """Register a spec's tasks with gymnasium, for ``gymnasium.make`` and the tools that take an id.

    :param spec: the ``.asap`` file (loaded and checked now: a broken spec raises
        :class:`asap_dsl.SpecError`).
    :param task: one task (default: every task of the spec).
    :param id: the id for that task (default ``asap/<file stem>-<task>-v0``; needs ``task`` when
        the spec has several).
    :param env_kwargs: keywords of :func:`asap_dsl.make_env` for every environment made
        (``reward="rho"``, ``seed=...``).
    :return: the ids registered (an id that is registered already is left as it is).
    :raises KeyError: an unknown task.
    :raises ValueError: ``id`` for a spec of several tasks without ``task``.
    """
    from pathlib import Path

    from .program import load

    prog = load(spec)
    tasks = [prog.task(task).name] if task is not None else list(prog.tasks)
    if id is not None and len(tasks) != 1:
        raise ValueError(f"{spec} has tasks {', '.join(tasks)}: name the one for id '{id}' with task=")
    path = str(Path(spec).resolve())
    ids = []
    for t in tasks:
        gid = id or env_id(spec, t)
        _register_id(gid, path, t, env_kwargs)
        ids.append(gid)
    return ids


class _LoaderThenRegister:
    """gymnasium's own loader, then the benchmark ids (a loader by its methods: importing
    importlib.abc would cost ``import asap_dsl`` 15 ms)."""

    def __init__(self, loader):
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module) -> None:
        self._loader.exec_module(module)
        register_benchmarks()

    def __getattr__(self, name):  # resources and the rest: gymnasium's loader
        return getattr(self._loader, name)


class _WhenGymnasiumLoads:
    """Registers the ids the moment gymnasium is imported (once: it removes itself)."""

    def find_spec(self, name, path=None, target=None):
        if name != "gymnasium":
            return None
        import importlib.util

        _remove_hook()
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.loader is not None:
            spec.loader = _LoaderThenRegister(spec.loader)
        return spec


_HOOK: _WhenGymnasiumLoads | None = None


def _remove_hook() -> None:
    global _HOOK
    if _HOOK is not None and _HOOK in sys.meta_path:
        sys.meta_path.remove(_HOOK)
    _HOOK = None


def install() -> None:
    """What ``import asap_dsl`` does: the benchmark ids now if gymnasium is loaded, else when it is."""
    global _HOOK
    if "gymnasium" in sys.modules:
        register_benchmarks()
    elif _HOOK is None:
        _HOOK = _WhenGymnasiumLoads()
        sys.meta_path.insert(0, _HOOK)
