"""The oracle's answers: per initial state (:class:`StateResult`), over a set of states with the
ceiling per tolerance (:class:`OracleReport`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from asap_dsl.stats import steps_summary, wilson_interval


def optional_int(v) -> Optional[int]:
    """A plain int (JSON has no numpy integers), None kept."""
    return None if v is None else int(v)


@dataclass
class StateResult:
    """The oracle's answer for one initial state."""

    index: int
    x0: np.ndarray
    steps: Optional[int]          # the minimum N, None if none up to the deadline
    status: str                   # solved | infeasible | solver_failed | timeout | nan
    verified: bool
    failures: int = 0             # IPOPT solves that failed (not a clean return status)
    solves: int = 0               # NLPs solved for this state (restarts included)
    lower_bound: int = 0          # where the N-search started
    actions: Optional[np.ndarray] = None   # [N, m]
    trajectory: Optional[np.ndarray] = None  # [N+1, n], the numpy replay
    seconds: float = 0.0
    restarts: int = 0             # of the solves, those from extra initial guesses
    source: Optional[str] = None  # set by tighten(): the task whose action sequence this is
    horizon: Optional[int] = None  # timeout: the last N searched (none feasible up to it)

    def to_dict(self, with_actions: bool = False) -> dict:
        # Plain ints and bools: the solver hands numpy's (a state's index from an index array).
        d = {"index": int(self.index), "x0": [float(v) for v in self.x0], "steps": optional_int(self.steps),
             "status": self.status, "verified": bool(self.verified), "failures": int(self.failures),
             "solves": int(self.solves), "restarts": int(self.restarts), "lower_bound": int(self.lower_bound),
             "seconds": round(float(self.seconds), 6)}
        if self.source is not None:
            d["source"] = self.source
        if self.horizon is not None:
            d["horizon"] = int(self.horizon)
        if with_actions:
            d["actions"] = None if self.actions is None else self.actions.tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "StateResult":
        acts = d.get("actions")
        return cls(d["index"], np.asarray(d["x0"], float), d["steps"], d["status"], d["verified"],
                   d.get("failures", 0), d.get("solves", 0), d.get("lower_bound", 0),
                   None if acts is None else np.asarray(acts, float), None, d.get("seconds", 0.0),
                   d.get("restarts", 0), d.get("source"), d.get("horizon"))


# --------------------------------------------------------------------------- statistics
@dataclass
class OracleReport:
    """Results over a set of initial states: minimum steps, statuses and the success ceiling."""

    file: str
    task: str
    system: str
    label: str
    deadline: int
    tolerances: tuple[int, ...]
    seed: Optional[int]
    results: list[StateResult]
    seconds: float = 0.0
    workers: int = 1
    extra: dict = field(default_factory=dict)

    @property
    def steps(self) -> np.ndarray:
        """Minimum steps per state (``inf`` where none up to the deadline or not solved)."""
        return np.array([np.inf if r.steps is None else r.steps for r in self.results], float)

    def counts(self) -> dict[str, int]:
        out = {"solved": 0, "infeasible": 0, "solver_failed": 0, "timeout": 0, "nan": 0}
        for r in self.results:
            out[r.status] = out.get(r.status, 0) + 1
        out["unverified"] = sum(1 for r in self.results if r.status == "solved" and not r.verified)
        out["states_with_solver_failures"] = sum(1 for r in self.results if r.failures)
        out["solver_failures"] = sum(r.failures for r in self.results)
        return out

    def ceiling(self, tolerance: int) -> dict:
        """Share of states with a minimum time <= tolerance, with its 95% Wilson interval."""
        n = len(self.results)
        k = int(np.sum(self.steps <= tolerance))
        lo, hi = wilson_interval(k, n)
        return {"tolerance": int(tolerance), "count": k, "states": n,
                "rate": k / n if n else float("nan"), "ci95": [lo, hi]}

    def distribution(self) -> dict:
        out = steps_summary(self.steps)
        if out["reached"]:
            s = self.steps[np.isfinite(self.steps)]
            out["histogram"] = {int(v): int(c) for v, c in zip(*np.unique(s.astype(int), return_counts=True))}
        return out

    def to_dict(self, with_states: bool = True, with_actions: bool = False) -> dict:
        d = {"file": self.file, "task": self.task, "system": self.system,
             "label": self.label, "bound": f"oracle ({self.label})", "deadline": self.deadline,
             "episodes": len(self.results), "seed": self.seed, "workers": self.workers,
             "seconds": round(self.seconds, 3),
             "unreachable_within_deadline": int(np.sum(~np.isfinite(self.steps))),
             "status": self.counts(), "distribution": self.distribution(),
             "ceiling": [self.ceiling(t) for t in self.tolerances]}
        if with_states:
            d["states"] = [r.to_dict(with_actions) for r in self.results]
        d.update(self.extra)
        return d
