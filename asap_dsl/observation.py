"""How training scales the policy's inputs: each state entry into [-1, 1] from a box, chosen per
entry (``observe scaling = init | state | none`` in a task, else the training preset's choice).

* ``init`` — the task's init box where that entry has width there, else the state space where it
  is bounded, else unscaled. An init range of zero width (``v`` starting at 0) would otherwise
  leave that entry raw beside entries scaled by ten.
* ``state`` — the state space where it is bounded, else the init box where it has width, else
  unscaled.
* ``none`` — every entry as it is.

Pure: reads a checked system, imports nothing heavy (``asapc show`` says it, training applies it
through :class:`asap_dsl.backends.rl.sb3.Scaling`).
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

__all__ = ["BOXES", "describe", "legacy_sources", "observation_sources", "shown_scaling"]

#: What each source is called in a sentence.
BOXES = {"init": "the init box", "state": "the state space", "none": "unscaled"}


def _usable(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", over="ignore"):
        return np.isfinite(lo) & np.isfinite(hi) & np.isfinite(hi - lo) & (hi > lo)


def _boxes(system, init_box):
    from .sampling import init_box as _init_box

    lo_i, hi_i = (np.asarray(x, dtype=np.float64) for x in _init_box(system, init_box))
    return (lo_i, hi_i), (np.asarray(system.state_low, dtype=np.float64), np.asarray(system.state_high, dtype=np.float64))


def observation_sources(system, init_box, mode: str) -> tuple[str, ...]:
    """Per state entry, the box its scaling comes from (``init``, ``state`` or ``none``) under
    ``mode`` (the rule of the module docstring); ``init_box``: the task's own, if it has one."""
    if mode not in BOXES:
        raise ValueError(f"observation scaling must be init, state or none; got '{mode}'")
    n = system.n_state
    if mode == "none":
        return ("none",) * n
    init, state = _boxes(system, init_box)
    order = (("init", init), ("state", state)) if mode == "init" else (("state", state), ("init", init))
    ok = {name: _usable(*box) for name, box in order}
    return tuple(next((name for name, _ in order if ok[name][i]), "none") for i in range(n))


def legacy_sources(system, init_box, mode: str) -> tuple[str, ...]:
    """The rule of runs trained before the per-entry choice: ``mode``'s box for every entry, an
    entry where it is unbounded or of zero width unscaled (how those runs' policies saw them)."""
    n = system.n_state
    if mode == "none":
        return ("none",) * n
    init, state = _boxes(system, init_box)
    ok = _usable(*(init if mode == "init" else state))
    return tuple(mode if ok[i] else "none" for i in range(n))


def describe(names: Sequence[str], sources: Sequence[str]) -> str:
    """``p by the init box, v by the state space`` (entries with the same source grouped)."""
    groups: dict[str, list[str]] = {}
    for name, src in zip(names, sources):
        groups.setdefault(src, []).append(name)
    parts = []
    for src, members in groups.items():
        who = ", ".join(members)
        parts.append(f"{who} unscaled" if src == "none" else f"{who} by {BOXES[src]}")
    return "; ".join(parts)


def shown_scaling(system, task) -> Optional[dict]:
    """What ``asapc show`` says of a task's scaling: None where it is the usual case (no
    ``observe scaling`` and every entry from the init box), else the mode and each entry's box."""
    mode = task.observe_scaling or "init"
    sources = observation_sources(system, task.init_box, mode)
    if task.observe_scaling is None and all(s == "init" for s in sources):
        return None
    return {"mode": mode, "explicit": task.observe_scaling is not None,
            "entries": dict(zip(system.state_names, sources))}
