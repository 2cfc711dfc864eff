"""Controllers that are not trained policies, judged by the same rollout as every policy.

* :class:`GreedyController` — the paper's second ablation: a one-step look-ahead that uses the
  simulator as a black box (it resets a copy of it to the current states and tries candidate
  actions) and takes the action whose next state has the highest robustness of ``asap`` — for a
  region goal, the one that most reduces the distance to it — among those that neither satisfy
  ``avoid`` nor leave the state space.
* :class:`OracleController` — the oracle's own action sequences replayed: the ceiling as a row
  of the report, and a check that the rollout reproduces the oracle's minimum times.
"""

from __future__ import annotations

import itertools
from typing import Optional, Sequence

import numpy as np

from asap_dsl.rewards import is_static, static_eval

__all__ = ["GreedyController", "OracleController", "candidate_actions"]


def candidate_actions(low: np.ndarray, high: np.ndarray, budget: int = 125) -> np.ndarray:
    """A grid over the action box with at most ``budget`` points, its corners included (the
    bang-bang actions a minimum-time problem often needs)."""
    m = len(low)
    per = max(2, int(np.floor(budget ** (1.0 / m))))
    axes = [np.linspace(lo, hi, per) for lo, hi in zip(low, high)]
    return np.array(list(itertools.product(*axes)), dtype=np.float64)


class GreedyController:
    """One-step look-ahead on a copy of the simulator (black-box access only)."""

    def __init__(self, program, task: Optional[str] = None, budget: int = 125):
        from asap_dsl.sim import build_simulator

        self.program = program
        self.task = program.task(task).model
        self.system = program.system
        self.candidates = candidate_actions(self.system.action_low, self.system.action_high, budget)
        self._build = lambda batch: build_simulator(self.system, batch, program.file)
        if not is_static(self.task.asap) and not self.task.asap_regions:
            raise ValueError(f"task {self.task.name}: the greedy controller needs `asap` to be a combination of "
                             "atoms, or to name regions whose distance it can reduce")
        self.sim = None
        self.B = 0

    def reset(self, states: np.ndarray) -> None:
        B, K = len(states), len(self.candidates)
        if self.sim is None or self.B != B:
            self.sim = self._build(B * K)
            self.B = B
            self.actions = np.tile(self.candidates, (B, 1))

    def _score(self, nxt: np.ndarray) -> np.ndarray:
        t = self.task
        with np.errstate(all="ignore"):
            if is_static(t.asap):
                score = static_eval(t.asap, nxt, False)
            else:
                regions = self.program.regions
                score = -np.min([regions[r].distance(nxt) for r in t.asap_regions], axis=0)
            bad = ~np.isfinite(nxt).all(axis=1)
            bad |= ((nxt < self.system.state_low) | (nxt > self.system.state_high)).any(axis=1)
            if t.avoid is not None and is_static(t.avoid):
                bad |= static_eval(t.avoid, np.where(np.isfinite(nxt), nxt, 0.0), True)
        score = np.where(np.isfinite(score), score, -np.inf)
        return np.where(bad, -np.inf, score)

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        B, K = len(states), len(self.candidates)
        self.sim.reset(np.repeat(states, K, axis=0))
        nxt = self.sim.step(self.actions)
        score = self._score(nxt).reshape(B, K)
        best = np.argmax(score, axis=1)  # all -inf (every move fails): the first candidate
        return self.candidates[best]


class OracleController:
    """Replays the oracle's action sequence of each initial state (zeros, clipped, once a sequence
    ends or where the oracle found none)."""

    def __init__(self, x0: np.ndarray, actions: Sequence[Optional[np.ndarray]], n_action: int):
        self.table = {np.asarray(x, dtype=np.float64).tobytes(): a for x, a in zip(x0, actions)}
        self.m = n_action
        self.plan: list[Optional[np.ndarray]] = []

    @classmethod
    def from_cache(cls, cached, n_action: int) -> "OracleController":
        return cls(cached.x0, cached.actions, n_action)

    def reset(self, states: np.ndarray) -> None:
        self.plan = [self.table.get(np.asarray(s, dtype=np.float64).tobytes()) for s in states]

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        out = np.zeros((len(states), self.m))
        for i, p in enumerate(self.plan):
            if p is not None and t < len(p):
                out[i] = p[t]
        return out
