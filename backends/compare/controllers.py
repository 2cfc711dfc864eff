"""Controllers that are not trained policies, judged by the same rollout as every policy.

* :class:`GreedyController` — the paper's second ablation: a one-step look-ahead that uses the
  simulator as a black box (it resets a copy of it to the current states and tries candidate
  actions) and takes the action whose next state has the highest robustness of ``asap`` — for a
  region goal, the one that most reduces the distance to it — among those that neither satisfy
  ``avoid`` nor leave the state space.
* :class:`OracleController` — the oracle's own action sequences replayed: the ceiling as a row
  of the report, and a check that the rollout reproduces the oracle's minimum times.
* :class:`LookaheadController` — any controller (a trained policy) refined on the simulator:
  at each step it tries candidate actions for the next few steps, follows the controller after
  them to the deadline, and takes the first action of the candidate that reaches ``asap``
  soonest (Bertsekas' rollout algorithm). The dynamics are deterministic, so it is never later
  than the controller it refines.
"""

from __future__ import annotations

import itertools
from typing import Optional, Sequence

import numpy as np

from asap_dsl.rewards import is_static, static_eval

__all__ = ["GreedyController", "LookaheadController", "OracleController", "candidate_actions", "lookahead_problem"]


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


def lookahead_problem(program, task: Optional[str] = None) -> Optional[str]:
    """Why :class:`LookaheadController` cannot refine a controller on ``task`` (None: it can).

    The look-ahead restarts the task from the current state; that is the same task only where
    nothing before that state matters: ``asap`` and ``avoid`` without temporal operators, and no
    ``observe time``."""
    model = program.task(task).model
    if not is_static(model.asap) or (model.avoid is not None and not is_static(model.avoid)):
        return (f"task {model.name}: the look-ahead needs `asap` and `avoid` without temporal operators "
                "(it restarts the task from the current state, where their history is lost)")
    if "time" in model.observe:
        return (f"task {model.name}: the look-ahead cannot refine a policy that observes time "
                "(it restarts the task from the current state)")
    return None


class _Prefix:
    """Fixed actions for the first steps of each entry (NaN: the base controller's), then the base."""

    def __init__(self, base, prefix: np.ndarray):
        self.base, self.prefix = base, prefix  # prefix [H, N, m]

    def reset(self, states: np.ndarray) -> None:
        pass

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        if t >= len(self.prefix):
            return self.base.act(obs, states, t)
        a = self.prefix[t]
        free = np.isnan(a).any(axis=1)
        if free.any():
            a = a.copy()
            a[free] = np.asarray(self.base.act(obs, states, t), dtype=np.float64)[free]
        return a


class LookaheadController:
    """``base`` refined by a look-ahead of ``steps`` steps on a copy of the task's environment.

    Candidates: the first action from the base's own and a grid over the action box (at most
    ``budget`` points, corners included); each later action of the look-ahead from the base's
    own and the box's corners (the bang-bang actions of minimum-time control). Each candidate
    is rolled out with the base after it to the deadline, on the same rules as any evaluation
    (:class:`asap_dsl.rollout.Evaluator`); the first action of the one that reaches soonest
    is taken, the base's own on ties and where none reaches. Because the base's continuation of
    the chosen candidate is among the next step's candidates, the predicted reach never gets
    later: on deterministic dynamics the refined controller reaches no later than ``base`` from
    any state (``tests/test_lookahead.py``).

    Cost: ``(1 + grid) x (1 + 2^m)^(steps - 1)`` candidates, each rolled out over the rest of the
    deadline, at every step. ``base`` is reset by those rollouts: it must act on any batch (a
    trained policy does). ``max_batch`` bounds the rows rolled out at once (memory).
    """

    def __init__(self, program, base, task: Optional[str] = None, steps: int = 2, budget: int = 27,
                 max_batch: int = 1 << 16):
        problem = lookahead_problem(program, task)
        if problem is not None:
            raise ValueError(problem)
        if not 1 <= int(steps) <= 3:
            raise ValueError(f"the look-ahead's steps must be 1, 2 or 3; got {steps}")
        self.program, self.base = program, base
        self.task = program.task(task).model.name
        self.deadline = program.task(task).model.deadline
        system = program.system
        self.low, self.high = system.action_low, system.action_high
        m = system.n_action
        free = np.full((1, m), np.nan)  # "the base's own action here"
        first = np.concatenate([free, candidate_actions(self.low, self.high, budget)])
        later = np.concatenate([free, candidate_actions(self.low, self.high, 2 ** m)])
        seqs = [[a] for a in first]
        for _ in range(int(steps) - 1):
            seqs = [s + [a] for s in seqs for a in later]
        self.sequences = np.array(seqs, dtype=np.float64)  # [K, steps, m]
        self.max_batch = int(max_batch)
        self.chunk = max(1, self.max_batch // len(self.sequences))
        self.inner = None
        self.refined = 0  # steps where a candidate beat the base's own action

    def reset(self, states: np.ndarray) -> None:
        from asap_dsl.rollout import Evaluator

        K = len(self.sequences)
        rows = min(len(states), self.chunk) * K
        if self.inner is None or len(self.inner.states) != rows:
            self.inner = Evaluator(self.program, self.task, np.repeat(states[:1], rows, axis=0))
        self.refined = 0

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        own = np.clip(np.asarray(self.base.act(obs, states, t), dtype=np.float64), self.low, self.high)
        out = own.copy()
        for lo in range(0, len(states), self.chunk):
            hi = min(lo + self.chunk, len(states))
            out[lo:hi] = self._refine(states[lo:hi], own[lo:hi], t)
        return out

    def _refine(self, states: np.ndarray, own: np.ndarray, t: int) -> np.ndarray:
        K, H = self.sequences.shape[:2]
        n = len(states)
        rows = len(self.inner.states) // K
        x = np.repeat(np.concatenate([states, np.repeat(states[-1:], rows - n, axis=0)]), K, axis=0)
        prefix = np.ascontiguousarray(np.tile(self.sequences, (rows, 1, 1)).transpose(1, 0, 2))
        result = self.inner.run(_Prefix(self.base, prefix), states=x, steps=self.deadline - t)
        reach = result.t_reach.reshape(rows, K)[:n]
        best = np.argmin(reach, axis=1)  # the first minimum: the base's own (index 0) on ties
        best[~(reach[np.arange(n), best] < reach[:, 0])] = 0
        self.refined += int(np.count_nonzero(best))
        first = self.sequences[best, 0]
        return np.where(np.isnan(first), own, first)
