"""The oracle's results on the seeded evaluation states, cached per spec hash, task, seed and count
(the planner's achievable steps beside them, in ``planner/``).

``asapc oracle``, ``asapc eval`` and reports compute the same minimum times for the same states;
the first one to need them stores them here and the others read them back. The cache lives in
``$ASAP_CACHE_DIR`` (default ``$XDG_CACHE_HOME/asap-dsl`` or ``~/.cache/asap-dsl``), one JSON file
per (spec hash, task, seed, episodes), written atomically. A changed spec has another hash, so a
stale entry is never read. A search under way keeps each finished chunk of states in a
``.partial.json`` beside its entry, so that an interrupted one (Ctrl-C, a killed process) resumes
where it stopped; the entry replaces it when done.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Optional

import numpy as np

from asap_dsl.limits import available_cores
from asap_dsl.runfiles import RunWriteError
from asap_dsl.runs import atomic_write_json, spec_hash

__all__ = ["CachedOracle", "cache_dir", "cache_path", "load", "load_prefix", "oracle_for", "solve_seeded", "store"]


def cache_dir() -> Path:
    if os.environ.get("ASAP_CACHE_DIR"):
        return Path(os.environ["ASAP_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "asap-dsl"


def cache_path(source: str, task: str, seed: int, episodes: int, kind: str = "oracle") -> Path:
    """Where the results of ``kind`` (``oracle``, or ``planner``: the achievable steps) are kept."""
    return cache_dir() / kind / f"{spec_hash(source)[:16]}-{task}-s{seed}-n{episodes}.json"


class CachedOracle:
    """The oracle's per-state results as stored: minimum steps (``inf`` where none within the
    deadline), the label (exact | local) and the action sequences that achieve them."""

    def __init__(self, data: dict):
        self.data = data
        states = data.get("states") or []
        self.steps = np.array([np.inf if s.get("steps") is None else float(s["steps"]) for s in states], float)
        self.x0 = np.array([s["x0"] for s in states], float) if states else np.zeros((0, 0))
        self.actions = [None if s.get("actions") is None else np.asarray(s["actions"], float) for s in states]
        self.label = data.get("label", "local")
        self.seconds = float(data.get("seconds", 0.0))
        self.unstored: Optional[str] = None  # why results just computed are not in the cache

    @property
    def bound(self) -> str:
        """``oracle (exact)``, ``oracle (local)`` or ``planner (achievable)``."""
        return self.data.get("bound") or f"oracle ({self.label})"

    @property
    def count(self) -> int:
        """The states it holds."""
        return int(self.steps.size)

    def head(self, k: int) -> "CachedOracle":
        """Its first ``k`` states (the same as an oracle on ``k`` states of the same draw)."""
        return CachedOracle({**self.data, "states": (self.data.get("states") or [])[:k]})

    def ceiling(self, tolerance: int) -> dict:
        from asap_dsl.stats import rate

        return {"tolerance": int(tolerance), **rate(self.steps <= tolerance)}


def load(source: str, task: str, seed: int, episodes: int, kind: str = "oracle") -> Optional[CachedOracle]:
    path = cache_path(source, task, seed, episodes, kind)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):  # RecursionError: nested too deep
        return None  # absent or damaged: recomputed by whoever needs it
    if not isinstance(data, dict) or len(data.get("states") or []) != episodes:
        return None
    return CachedOracle(data)


def load_prefix(source: str, task: str, seed: int, states: np.ndarray, kind: str = "oracle") -> Optional[CachedOracle]:
    """The cached results whose states are a prefix of ``states`` or ``states`` a prefix of theirs
    (the draw of :func:`asap_dsl.sampling.task_states` is one stream: ``n`` states of a seed are
    the first ``n`` of more, except where a state was redrawn out of ``avoid``; so each state is
    compared). The smallest superset is preferred (exact: cut to ``len(states)``), else the
    largest subset (its :attr:`CachedOracle.count` says how many of the states it covers)."""
    n = len(states)
    found = []
    for path in (cache_dir() / kind).glob(f"{spec_hash(source)[:16]}-{task}-s{seed}-n*.json"):
        try:
            m = int(path.stem.rsplit("-n", 1)[1])
        except ValueError:
            continue
        found.append(m)
    # supersets, smallest first; then subsets, largest first
    for m in sorted((m for m in found if m >= n)) + sorted((m for m in found if m < n), reverse=True):
        hit = load(source, task, seed, m, kind)
        if hit is None or hit.count == 0:
            continue
        k = min(n, m)
        if hit.x0.shape[1:] == states.shape[1:] and np.array_equal(hit.x0[:k], np.asarray(states, float)[:k]):
            return hit.head(k) if m > k else hit
    return None


def store(source: str, report) -> Path:
    """Store an :class:`~asap_dsl.backends.oracle.solver.OracleReport` computed on the seeded states
    (the planner's apart from the oracle's); the partial results of its search go."""
    path = cache_path(source, report.task, report.seed, len(report.results), _kind(report.label))
    atomic_write_json(path, report.to_dict(with_states=True, with_actions=True))
    _partial_path(source, report.task, report.seed, len(report.results)).unlink(missing_ok=True)
    return path


def _partial_path(source: str, task: str, seed: int, episodes: int) -> Path:
    return cache_path(source, task, seed, episodes).with_suffix(".partial.json")


def _read_partial(path: Path, states: np.ndarray, time_limit: float) -> tuple[list, float]:
    """The results kept by an interrupted search of these states with this time limit, and its
    seconds; nothing when the file is absent, damaged or of other states."""
    from .results import StateResult

    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        if data.get("time_limit") != time_limit:
            return [], 0.0
        done = [StateResult.from_dict(d) for d in data["results"]]
        for r in done:
            if not (0 <= int(r.index) < len(states) and np.array_equal(r.x0, states[r.index])):
                return [], 0.0
        return done, float(data.get("seconds", 0.0))
    except (OSError, ValueError, TypeError, KeyError, AttributeError, IndexError, RecursionError):
        return [], 0.0


def solve_seeded(prog, task: str, seed: int, episodes: int, workers: int, time_limit: Optional[float] = None,
                 progress=None):
    """:func:`~asap_dsl.backends.oracle.solver.run` on the seeded states, resumable: each chunk of
    states is kept as it ends (``.partial.json`` beside the cache entry), and a search of the same
    states and time limit begins with what an interrupted one kept. An unwritable cache only
    costs the resumption. ``progress(k)`` is told of the states kept from before as well."""
    from asap_dsl.sampling import task_states

    from .search import STATE_TIME_LIMIT
    from .solver import run

    limit = STATE_TIME_LIMIT if time_limit is None else float(time_limit)
    states = task_states(prog.system, prog.task(task).model, episodes, seed=seed)
    path = _partial_path(prog.source, task, seed, episodes)
    done, before = _read_partial(path, states, limit)
    if done and progress is not None:
        progress(len(done))
    kept, start = list(done), time.perf_counter()

    def keep(part) -> None:
        kept.extend(part)
        try:
            atomic_write_json(path, {"time_limit": limit, "seconds": before + time.perf_counter() - start,
                                     "results": [r.to_dict(with_actions=True) for r in kept]})
        except RunWriteError:
            pass

    report = run(prog, task, episodes=episodes, seed=seed, workers=workers, time_limit=limit, progress=progress,
                 done=done, on_part=keep)
    report.seconds += before
    return report


def _kind(label: str) -> str:
    from .planner import LABEL

    return "planner" if label == LABEL else "oracle"


def oracle_for(prog, task: str, seed: int, episodes: int, compute: bool = True,
               workers: Optional[int] = None, progress=None, started=None,
               partial: bool = False) -> Optional[CachedOracle]:
    """The cached results, computed (and stored) first when absent and ``compute``; None for a
    task the oracle cannot express (nothing to compare against). A cache of more states counts
    where these are its first (:func:`load_prefix`); with ``partial``, one of fewer states too,
    where its states are the first of these (then its :attr:`~CachedOracle.count` is less than
    ``episodes``, and nothing is computed). A black-box system has the
    planner's achievable steps when ``asapc oracle`` has stored them (they take minutes per
    hundred states, so they are never computed on the way). ``progress(k)`` is told of states
    solved, ``started()`` before the computation begins."""
    kind = "planner" if prog.system.kind == "simulator" else "oracle"
    hit = load(prog.source, task, seed, episodes, kind)
    if hit is None:
        from asap_dsl.sampling import task_states

        states = task_states(prog.system, prog.task(task).model, episodes, seed=seed)
        hit = load_prefix(prog.source, task, seed, states, kind)
        if hit is not None and hit.count < episodes and not partial:
            hit = None  # fewer states than asked
    if hit is not None or not compute or kind == "planner":
        return hit
    if started is not None:
        started()
    from .solver import OracleUnsupported

    try:
        report = solve_seeded(prog, task, seed, episodes, available_cores() if workers is None else workers,
                              progress=progress)
    except OracleUnsupported:
        return None
    try:
        store(prog.source, report)
    except RunWriteError as err:  # the results stand; only the next caller computes them again
        hit = CachedOracle(report.to_dict(with_states=True, with_actions=True))
        hit.unstored = str(err)
        return hit
    return load(prog.source, task, seed, episodes)
