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
from typing import Callable, Optional, Sequence

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
    """Fixed actions for the first steps of each entry (NaN: the base controller's), then the base.

    The base acts on the rows it is free to, padded to a power of two rows: a jitted policy
    compiles once per batch shape, and the free rows change from step to step."""

    def __init__(self, base, prefix: np.ndarray):
        self.base, self.prefix = base, prefix  # prefix [H, N, m]

    def reset(self, states: np.ndarray) -> None:
        pass

    def _base(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        n = len(states)
        pad = (1 << (n - 1).bit_length()) - n
        if pad:
            obs = np.concatenate([obs, np.repeat(obs[-1:], pad, axis=0)])
            states = np.concatenate([states, np.repeat(states[-1:], pad, axis=0)])
        return np.asarray(self.base.act(obs, states, t), dtype=np.float64)[:n]

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        if t >= len(self.prefix):
            return self._base(obs, states, t)
        a = self.prefix[t]
        free = np.isnan(a).any(axis=1)
        if free.any():
            a = a.copy()
            a[free] = self._base(obs[free], states[free], t)
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
    base after it as far as it could still win (below), on the rules of every evaluation
    (:class:`asap_dsl.rollout.Evaluator`), and the one that reaches ``asap`` soonest gives the action (the base's own on
    ties and where none reaches). Because the rest of the chosen candidate is among the next
    step's candidates, the predicted reach never gets later: on deterministic dynamics the
    refined controller reaches no later than ``base`` from any state (``tests/test_lookahead.py``).

    Cost: ``2 + grid x len(hold_ladder(hold))`` candidates per state still on its way, each rolled
    out only as far as the step its current choice reaches ``asap`` (a candidate reaching later
    cannot win; the base's own reach bounds the first step; to the deadline where nothing reaches),
    at every step. States are refined in groups of like reach (sorted), so a slow state does not
    lengthen a quick one's rollouts. ``base`` is reset by those rollouts: it must act on any batch
    (a trained policy does). ``max_batch`` bounds the rows rolled out at once (memory; default
    65,536, 2,048 on a black box, whose every row holds a simulator's own data).
    """

    def __init__(self, program, base, task: Optional[str] = None, hold: int = 8, budget: int = 27,
                 max_batch: Optional[int] = None, progress: Optional[Callable[[int, int, int], None]] = None):
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
        self.inner: dict[int, object] = {}  # Evaluators by their rows, the last few
        self.plan = np.empty((0, H, m))
        self.due = np.empty(0)  # per state, the step its chosen candidate reaches asap (inf: none does)
        self.refined = 0  # steps where a candidate beat the base's own action
        self.progress = progress  # told (steps done, deadline, states whose choice has reached) after each step

    def _evaluator(self, rows: int, like: np.ndarray):
        from asap_dsl.rollout import Evaluator

        if rows not in self.inner:
            # Building one takes milliseconds; a black box's rows each hold a simulator's data.
            if len(self.inner) >= (1 if self.program.system.kind == "simulator" else 8):
                self.inner.clear()
            self.inner[rows] = Evaluator(self.program, self.task, np.repeat(like[:1], rows, axis=0))
        return self.inner[rows]

    def reset(self, states: np.ndarray) -> None:
        from asap_dsl.rollout import Evaluator

        self.plan = np.full((len(states),) + self.sequences.shape[1:], np.nan)
        # The base's own reach bounds the first step's rollouts (its own action is a candidate).
        self.due = Evaluator(self.program, self.task, states).run(self.base).t_reach.astype(np.float64)
        self.refined = 0

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        own = np.clip(np.asarray(self.base.act(obs, states, t), dtype=np.float64), self.low, self.high)
        out = own.copy()
        for idx, steps in self._groups(t):
            out[idx] = self._refine(states[idx], own[idx], idx, t, steps)
        if self.progress is not None:
            self.progress(t + 1, self.deadline, int(np.count_nonzero(self.due <= t + 1)))
        return out

    #: A rolled-out step's fixed cost (the policy's call, the simulator's, Python's), in rows:
    #: measured 0.25 ms against 0.9 us a row on attitude and the pendulum.
    STEP_ROWS = 300

    def _groups(self, t: int) -> list[tuple[np.ndarray, int]]:
        """The states still to refine at step ``t``, in groups rolled out together, each with the
        steps it needs: as far as its latest chosen reach (a candidate reaching later cannot win),
        to the deadline where nothing reaches. States of one reach form a group; neighbouring
        groups merge where one rollout to the later reach costs less than two."""
        todo = np.flatnonzero(~(self.due <= t))  # a state whose choice has reached asap is decided
        if not len(todo):
            return []
        left = self.deadline - t
        steps = np.minimum(self.due[todo] - t, left)
        steps = np.where(np.isfinite(steps), np.maximum(steps, 1), left).astype(np.int64)
        order = np.argsort(steps, kind="stable")
        todo, steps = todo[order], steps[order]
        cuts = np.flatnonzero(np.diff(steps)) + 1
        cost = lambda n, h: (n * self.K + self.STEP_ROWS) * h  # noqa: E731
        groups: list[list[int]] = []  # [first, end, steps] over the sorted states
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(todo)]):
            h = int(steps[a])
            if groups:
                g = groups[-1]
                if b - g[0] <= self.chunk and cost(b - g[0], h) <= cost(g[1] - g[0], g[2]) + cost(b - a, h):
                    g[1], g[2] = b, h
                    continue
            groups.append([a, b, h])
        return [(todo[lo:min(lo + self.chunk, b)], h) for a, b, h in groups for lo in range(a, b, self.chunk)]

    def _refine(self, states: np.ndarray, own: np.ndarray, idx: np.ndarray, t: int, steps: int) -> np.ndarray:
        """The first actions for ``states`` (the states ``idx``), rolled out ``steps`` steps; their
        plans and reach are moved on."""
        K, n = self.K, len(states)
        plan = self.plan[idx]
        cands = np.concatenate([np.broadcast_to(self.sequences, (n,) + self.sequences.shape), plan[:, None]], axis=1)
        prefix = np.ascontiguousarray(cands.reshape(n * K, *cands.shape[2:]).transpose(1, 0, 2))
        inner = self._evaluator(n * K, states)
        result = inner.run(_Prefix(self.base, prefix), states=np.repeat(states, K, axis=0), steps=steps)
        reach = result.t_reach.reshape(n, K)
        best = np.argmin(reach, axis=1)  # the first minimum: the base's own (index 0) on ties
        best[~(reach[np.arange(n), best] < reach[:, 0])] = 0
        self.refined += int(np.count_nonzero(best))
        chosen = cands[np.arange(n), best]
        plan[:, :-1], plan[:, -1] = chosen[:, 1:], np.nan
        self.plan[idx] = plan
        self.due[idx] = t + reach[np.arange(n), best]
        return np.where(np.isnan(chosen[:, 0]), own, chosen[:, 0])
