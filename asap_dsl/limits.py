"""The limits that keep every input within bounded time and memory, in one place.

Each is far beyond any real spec and stops input that would otherwise hang or exhaust the
machine. ``asapc``'s global flags raise the ones that are a matter of resources
(``--max-spec-size MB``, ``--max-deadline STEPS``, ``--max-substeps N``); from Python, set the
fields of :data:`LIMITS` (or use :func:`raised`). The nesting limits are not flags: they keep
the tree walks within Python's stack, and a chain (a + b + ..., a and b and ...) never counts.
The processes a run may start are bounded by the cores (:func:`available_cores`).
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass, fields, replace
from typing import Iterator


@dataclass
class Limits:
    #: bytes of a spec file read (``asapc --max-spec-size MB``)
    spec_bytes: int = 10 * 1024 * 1024
    #: steps of the longest deadline, hence of every episode, window and oracle horizon
    #: (``asapc --max-deadline STEPS``); windows longer than the deadline are cut to it
    deadline_steps: int = 1_000_000
    #: integrator substeps per step (``asapc --max-substeps N``)
    substeps: int = 1000
    #: initial states of one evaluation or oracle run
    episodes: int = 1_000_000
    #: nested operators in one expression as written (parentheses, calls, not, -, temporal)
    nesting: int = 100
    #: nested operators of a formula with the formulas it uses written out
    formula_depth: int = 200
    #: nodes of a formula with the formulas it uses written out (one used twice counts twice)
    formula_size: int = 100_000


#: The limits in force in this process.
LIMITS = Limits()


@contextlib.contextmanager
def raised(**changes: int) -> Iterator[Limits]:
    """``with raised(deadline_steps=10**7): ...``: other limits for the block, then the old ones."""
    names = {f.name for f in fields(Limits)}
    unknown = set(changes) - names
    if unknown:
        raise TypeError(f"unknown limit(s) {', '.join(sorted(unknown))}; the limits are {', '.join(sorted(names))}")
    old = replace(LIMITS)
    for k, v in changes.items():
        setattr(LIMITS, k, int(v))
    try:
        yield LIMITS
    finally:
        for f in fields(Limits):
            setattr(LIMITS, f.name, getattr(old, f.name))


def available_cores() -> int:
    """The cores this process may run on: the default number of worker processes everywhere, and
    their cap unless forced (more processes than cores only slow every one of them down)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


__all__ = ["LIMITS", "Limits", "available_cores", "raised"]
