"""Controllers that are not trained policies, judged by the same rollout as every policy.

* :class:`GreedyController` — the paper's second ablation: a one-step look-ahead that uses the
  simulator as a black box (it resets a copy of it to the current states and tries candidate
  actions) and takes the action whose next state has the highest robustness of ``asap`` — for a
  region goal, the one that most reduces the distance to it — among those that neither satisfy
  ``avoid`` nor leave the state space.
* :class:`OracleController` — the oracle's own action sequences replayed: the ceiling as a row
  of the report, and a check that the rollout reproduces the oracle's minimum times.
* :class:`LookaheadController` — any controller (a trained policy) refined on the simulator:
  at each step it tries candidate actions held for a few steps, follows the controller after
  them to the deadline, and takes the first action of the candidate that reaches ``asap``
  soonest (Bertsekas' rollout algorithm). The dynamics are deterministic, so it is never later
  than the controller it refines.
"""

from __future__ import annotations

import itertools
from typing import Optional, Sequence

import numpy as np

from asap_dsl.rewards import is_static, static_eval

__all__ = ["GreedyController", "LookaheadController", "OracleController", "candidate_actions", "hold_ladder",
           "lookahead_problem"]


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
        if free.any():  # on every row: a jitted policy compiles once per batch shape (a subset was slower)
            a = a.copy()
            a[free] = np.asarray(self.base.act(obs, states, t), dtype=np.float64)[free]
        return a


def hold_ladder(longest: int) -> list[int]:
    """How long the look-ahead holds a candidate action: 1, 2, 3, 5, 8, ... (each the sum of the
    two before it) up to ``longest``, which closes the ladder."""
    ladder = [1, 2]
    while ladder[-1] + ladder[-2] < longest:
        ladder.append(ladder[-1] + ladder[-2])
    return [h for h in ladder if h < longest] + [int(longest)]


class LookaheadController:
    """``base`` refined on a copy of the task's environment by holding candidate actions for a
    few steps and following ``base`` after them.

    Candidates at each step, for each state: the base's own action; every point of a grid over
    the action box (at most ``budget`` points, corners included: the bang-bang actions of
    minimum-time control) held for 1, 2, 3, 5, ... up to ``hold`` steps (:func:`hold_ladder`);
    and what is left of the candidate chosen at the step before. Each is rolled out with the
    base after it to the deadline, on the rules of every evaluation (:class:`asap_dsl.rollout.
    Evaluator`), and the one that reaches ``asap`` soonest gives the action (the base's own on
    ties and where none reaches). Because the rest of the chosen candidate is among the next
    step's candidates, the predicted reach never gets later: on deterministic dynamics the
    refined controller reaches no later than ``base`` from any state (``tests/test_lookahead.py``).

    Cost: ``2 + grid x len(hold_ladder(hold))`` candidates, each rolled out over the rest of the
    deadline, at every step. ``base`` is reset by those rollouts: it must act on any batch (a
    trained policy does). ``max_batch`` bounds the rows rolled out at once (memory; default 65,536,
    2,048 on a black box, whose every row holds a simulator's own data).
    """

    def __init__(self, program, base, task: Optional[str] = None, hold: int = 8, budget: int = 27,
                 max_batch: Optional[int] = None):
        problem = lookahead_problem(program, task)
        if problem is not None:
            raise ValueError(problem)
        model = program.task(task).model
        if not 1 <= int(hold) <= model.deadline:
            raise ValueError(f"the look-ahead holds an action for 1 to {model.deadline} steps (the deadline); "
                             f"got {hold}")
        self.program, self.base = program, base
        self.task, self.deadline = model.name, model.deadline
        system = program.system
        self.low, self.high = system.action_low, system.action_high
        self.holds = hold_ladder(int(hold))
        m, H = system.n_action, self.holds[-1]
        seqs = [np.full((H, m), np.nan)]  # NaN: the base's own action at that step
        for a in candidate_actions(self.low, self.high, budget):
            for h in self.holds:
                seq = np.full((H, m), np.nan)
                seq[:h] = a
                seqs.append(seq)
        self.sequences = np.array(seqs, dtype=np.float64)  # [K, H, m]; each state's plan comes last
        self.K = len(self.sequences) + 1
        if max_batch is None:
            max_batch = 1 << 11 if system.kind == "simulator" else 1 << 16
        self.chunk = max(1, int(max_batch) // self.K)
        self.inner = None
        self.plan = np.empty((0, H, m))
        self.refined = 0  # steps where a candidate beat the base's own action

    def reset(self, states: np.ndarray) -> None:
        from asap_dsl.rollout import Evaluator

        rows = min(len(states), self.chunk) * self.K
        if self.inner is None or len(self.inner.states) != rows:
            self.inner = Evaluator(self.program, self.task, np.repeat(states[:1], rows, axis=0))
        self.plan = np.full((len(states),) + self.sequences.shape[1:], np.nan)
        self.refined = 0

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        own = np.clip(np.asarray(self.base.act(obs, states, t), dtype=np.float64), self.low, self.high)
        out = own.copy()
        for lo in range(0, len(states), self.chunk):
            hi = min(lo + self.chunk, len(states))
            out[lo:hi] = self._refine(states[lo:hi], own[lo:hi], self.plan[lo:hi], t)
        return out

    def _refine(self, states: np.ndarray, own: np.ndarray, plan: np.ndarray, t: int) -> np.ndarray:
        """The first actions for ``states``; ``plan`` (a view of the plans) is moved on a step."""
        K, n = self.K, len(states)
        rows = len(self.inner.states) // K
        pad = rows - n  # the last chunk: filled with copies of its last state
        cands = np.concatenate([np.broadcast_to(self.sequences, (n,) + self.sequences.shape), plan[:, None]], axis=1)
        x = np.concatenate([states, np.repeat(states[-1:], pad, axis=0)])
        c = np.concatenate([cands, np.repeat(cands[-1:], pad, axis=0)])
        prefix = np.ascontiguousarray(c.reshape(rows * K, *c.shape[2:]).transpose(1, 0, 2))
        result = self.inner.run(_Prefix(self.base, prefix), states=np.repeat(x, K, axis=0), steps=self.deadline - t)
        reach = result.t_reach.reshape(rows, K)[:n]
        best = np.argmin(reach, axis=1)  # the first minimum: the base's own (index 0) on ties
        best[~(reach[np.arange(n), best] < reach[:, 0])] = 0
        self.refined += int(np.count_nonzero(best))
        chosen = cands[np.arange(n), best]
        plan[:, :-1], plan[:, -1] = chosen[:, 1:], np.nan
        return np.where(np.isnan(chosen[:, 0]), own, chosen[:, 0])
