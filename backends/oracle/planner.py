"""The sampling planner: an achievable number of steps per initial state, through the simulator.

For every system — a black-box ``simulator`` included — and every task, the planner searches
action sequences from one initial state for the first step at which ``asap`` holds, with
``avoid``, leaving the state space and a non-finite state as failure. Every candidate is rolled
out by the project's own batched rollout (:class:`asap_dsl.rollout.Evaluator`, the very
environment policies are judged in), so what the planner finds is what a controller replaying
its sequence achieves; :mod:`~asap_dsl.backends.oracle.planning` replays every found sequence
once more before it counts. A found sequence's steps are an upper bound on that state's minimum,
so the share of states within a tolerance is a **lower bound on the ceiling**: the label is
``planner (achievable)``.

The search (docs/oracle.md, "The planner"): predictive sampling by default (cross-entropy and
MPPI as the other update rules) over piecewise-constant action sequences — ``knots`` values per
action held for ``hold`` steps each, in the action box's normalised units — with a Gaussian per
knot, clipped to the box (so bang-bang actions, which minimum time often needs, have mass). The
first population also holds constant actions (the centre and corners of the box), the warm
starts, and periodic sequences (:meth:`Planner.periodic`: locomotion needs coordinated periodic
actions, which noise around "do nothing" almost never produces). Each iteration rolls
``samples`` candidates out as one batch; the cost of a candidate is a soft first hitting time,

    cost = min over steps t before any failure of  t + D * v_t / v_0,

where ``v_t = max(0, -rho_t)`` is how far ``asap``'s robustness is from holding at step t
(``v_0`` at the initial state) and ``D`` the deadline: a candidate that reaches at step t costs
at most t, one that only comes close is ranked by how close and how soon. A failure before
reaching adds ``D``. The elite (the cheapest ``elite`` share) sets the next mean and spread
(smoothed); the best elites are carried over. Once a sequence reaches at step N, candidates are
rolled out for N - 1 steps only: only an earlier arrival can improve on it. Then the polish
(:meth:`Planner.polish`, within ``polish`` times the sampling's rollouts): descents where nothing
reached, and the shortening of what did (at most ``shorten_seconds`` per state).

Budget: ``samples`` candidates per iteration, ``iterations`` iterations, and the per-state time
limit (as the oracle's ``--state-time-limit``). The random numbers of a state are seeded by the
seed and the state itself, so a state's result depends neither on the order of the states nor on
the number of workers.
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import asdict, dataclass, replace
from typing import Optional, Sequence

import numpy as np

from asap_dsl.rollout import Evaluator
from asap_dsl.sampling import EVAL_SEED

from .results import StateResult, optional_int
from .search import STATE_TIME_LIMIT

__all__ = ["BOUND", "LABEL", "METHODS", "PlannedState", "Planner", "PlannerBudget", "PlannerUnsupported",
           "SequenceController"]

#: The planner's results are achievable steps: upper bounds on each minimum, a lower bound on the ceiling.
LABEL = "achievable"
BOUND = f"planner ({LABEL})"
METHODS = ("cem", "mppi", "ps")


class PlannerUnsupported(ValueError):
    """The planner cannot run on this system or task (one sentence says why)."""


@dataclass(frozen=True)
class PlannerBudget:
    """What the planner may spend per initial state, and how it searches.

    ``samples`` candidate sequences per iteration, ``iterations`` iterations (the time limit per
    state caps both); ``hold`` steps per knot of the piecewise-constant sequences; ``method``:
    ``cem`` (cross-entropy), ``mppi`` (path-integral weights) or ``ps`` (predictive sampling:
    the best candidate is the next mean, the spread fixed). ``steps_per_second``: 0 reads the
    time limits on the wall clock; above 0 a second of them is that many simulator steps rolled
    out, so that the search, and what it finds, is the same on every machine (a training run's
    demonstrations; a slower machine takes longer instead of finding less).
    """

    samples: int = 128
    iterations: int = 60
    hold: int = 1
    method: str = "ps"
    elite: float = 0.1
    smoothing: float = 0.2
    sigma: float = 0.5
    keep: float = 0.5
    pilot: int = 4
    pilot_hold: int = 5
    islands: int = 8
    exchange: int = 16
    refine_sigma: float = 0.3
    floor: float = 0.02
    polish: float = 30.0
    shorten_seconds: float = 2.0
    descents: int = 8
    steps_per_second: float = 0.0

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"the planner's method must be one of {', '.join(METHODS)}; got {self.method!r}")
        for name in ("samples", "iterations", "hold"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"the planner's {name} must be a whole number, at least 1; got {v!r}")
        if self.samples < 8:
            raise ValueError(f"the planner needs at least 8 samples per iteration; got {self.samples}")
        for name in ("polish", "shorten_seconds", "steps_per_second"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0 or not math.isfinite(v):
                raise ValueError(f"the planner's {name} must be a finite number, at least 0; got {v!r}")

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class PlannedState(StateResult):
    """The planner's answer for one state: ``steps`` achieved by ``actions`` (an upper bound on
    the state's minimum; ``verified`` once replayed), ``rollouts`` candidates in ``iterations``.
    Statuses: ``solved``, ``not_found`` (no candidate reached within the deadline), ``timeout``
    (none reached before the time limit), ``nan`` (a non-finite initial state), ``unverified``
    (the replay did not reach: not counted)."""

    rollouts: int = 0
    iterations: int = 0

    def to_dict(self, with_actions: bool = False) -> dict:
        d = {"index": int(self.index), "x0": [float(v) for v in self.x0], "steps": optional_int(self.steps),
             "status": self.status, "verified": bool(self.verified), "rollouts": int(self.rollouts),
             "iterations": int(self.iterations), "seconds": round(float(self.seconds), 6)}
        if self.source is not None:
            d["source"] = self.source
        if with_actions:
            d["actions"] = None if self.actions is None else self.actions.tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "PlannedState":
        acts = d.get("actions")
        return cls(d["index"], np.asarray(d["x0"], float), d["steps"], d["status"], d["verified"],
                   actions=None if acts is None else np.asarray(acts, float).reshape(len(acts), -1) if acts else np.zeros((0, 0)),
                   seconds=d.get("seconds", 0.0), source=d.get("source"), rollouts=d.get("rollouts", 0),
                   iterations=d.get("iterations", 0))


class SequenceController:
    """Replays one action sequence per entry of the batch (``[B, H, m]``; zeros after step H)."""

    def __init__(self, actions: np.ndarray):
        self.actions = np.asarray(actions, dtype=np.float64)

    def reset(self, states: np.ndarray) -> None:
        if len(states) != len(self.actions):
            raise ValueError(f"{len(self.actions)} sequences for a batch of {len(states)}")

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        if t < self.actions.shape[1]:
            return self.actions[:, t]
        return np.zeros((len(self.actions), self.actions.shape[2]))


def state_seed(seed: int, x0: np.ndarray) -> np.random.Generator:
    """The random numbers of one state: a function of the seed and the state's own numbers."""
    digest = hashlib.sha256(np.asarray(x0, dtype=np.float64).tobytes()).digest()
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, *np.frombuffer(digest[:16], dtype=np.uint32).tolist()])


def check_state_setting(evaluator: Evaluator, system) -> None:
    """One sentence when the simulator cannot be started from a given state (the planner rolls
    every candidate out from the state it plans for)."""
    from asap_dsl.sim import SimulatorError

    core = evaluator.core
    lo = np.clip(system.init_low, system.state_low, system.state_high)
    hi = np.clip(system.init_high, system.state_low, system.state_high)
    frac = (np.arange(core.B)[:, None] + 1.0) / (core.B + 1.0)  # another state in every entry
    probe = np.where(np.isfinite(lo) & np.isfinite(hi), lo + frac * (hi - lo), 0.0)
    try:
        out = core.sim.reset(probe)
        same = np.allclose(out, probe, rtol=1e-9, atol=1e-9)
        why = "its reset(states) returned other states than it was given"
    except SimulatorError as err:
        same, why = False, str(err).split(": ", 2)[-1]
    if not same:
        raise PlannerUnsupported(
            f"{core.sim.where}: simulator \"{system.simulator or system.kind}\" cannot be started from a given "
            f"state ({why}); the planner needs reset(states [B, n]) to set every entry to the given state "
            "(docs/language.md, the simulator protocol)")


class Planner:
    """The sampling planner for one task (built once, planned for many states).

    :param prog: the program (:func:`asap_dsl.load`); any system, a black box included.
    :param task: the task's name (default: the program's only or first task).
    :param budget: samples, iterations and the search's settings (:class:`PlannerBudget`).
    :param time_limit: seconds of search per state, then the best found so far (``timeout``
        when none reached).
    :param seed: the seed of every state's random numbers (with the state itself).
    :raises PlannerUnsupported: a simulator that cannot be started from a given state.
    :raises KeyError: an unknown task.
    """

    def __init__(self, prog, task: Optional[str] = None, budget: Optional[PlannerBudget] = None,
                 time_limit: float = STATE_TIME_LIMIT, seed: int = EVAL_SEED):
        self.prog = prog
        self.budget = budget or PlannerBudget()
        if not (isinstance(time_limit, (int, float)) and math.isfinite(time_limit) and time_limit > 0):
            raise ValueError(f"the time limit per state must be a positive number of seconds; got {time_limit!r}")
        self.time_limit = float(time_limit)
        self.seed = int(seed)
        self.task = prog.task(task)
        self.task_name = self.task.name
        tm = self.task.model
        sysm = self.system = prog.system
        self.n, self.m = sysm.n_state, sysm.n_action
        self.deadline = int(tm.deadline)
        self.tolerances = tuple(int(t) for t in tm.tolerances)
        self.low, self.high = sysm.action_low.astype(float), sysm.action_high.astype(float)
        self.K = self.budget.samples
        probe = np.zeros((self.K, self.n))
        self.evaluator = Evaluator(prog, self.task_name, probe)
        check_state_setting(self.evaluator, sysm)
        self.knots = -(-self.deadline // self.budget.hold)
        self.weight = 10.0
        self.refine_terminal = False
        self.rolled = 0  # simulator steps rolled out (rows x steps), the clock under ``steps_per_second``

    def now(self) -> float:
        """The clock the time limits are read on, in seconds: the wall clock, or the simulator steps
        rolled out so far at the budget's ``steps_per_second``."""
        rate = self.budget.steps_per_second
        return self.rolled / rate if rate > 0 else time.perf_counter()

    # ------------------------------------------------------------------ sequences
    def actions(self, z: np.ndarray) -> np.ndarray:
        """Knots in normalised units ``[K, knots, m]`` (in [-1, 1]) as actions ``[K, deadline, m]``."""
        u = self.low + (np.clip(z, -1.0, 1.0) + 1.0) * 0.5 * (self.high - self.low)
        return np.repeat(u, self.budget.hold, axis=1)[:, : self.deadline]

    def evaluate(self, x0: np.ndarray, z: np.ndarray, steps: int, terminal: bool) -> tuple[np.ndarray, np.ndarray]:
        """Roll the candidates ``z`` out from ``x0`` for ``steps`` steps: ``(t_reach [K], cost [K])``."""
        K = len(z)
        U = self.actions(z)
        if K < self.K:  # pad to the environment's batch (the padding is never read)
            U = np.concatenate([U, np.repeat(U[-1:], self.K - K, axis=0)])
        res = self.evaluator.run(SequenceController(U[:, :steps]), states=np.tile(x0, (self.K, 1)), steps=steps,
                                 robustness=True)
        self.rolled += self.K * steps
        t_reach, rho = res.t_reach[:K], res.rho[:K]
        failed = np.isin(res.end_reason[:K], ("avoid", "out_of_bounds", "non_finite")) & ~np.isfinite(t_reach)
        return t_reach, self.cost(t_reach, rho, failed, terminal)

    def try_sequences(self, x0: np.ndarray, sequences: Sequence[np.ndarray], steps: int) -> np.ndarray:
        """The first step in ``asap`` (inf: none within ``steps``) of each action sequence from ``x0``."""
        out = []
        for at in range(0, len(sequences), self.K):
            part = sequences[at: at + self.K]
            U = np.zeros((self.K, steps, self.m)) + (self.low + self.high) / 2
            for i, a in enumerate(part):
                a = np.asarray(a, dtype=np.float64).reshape(-1, self.m)[:steps]
                U[i, : len(a)] = a
            res = self.evaluator.run(SequenceController(U), states=np.tile(x0, (self.K, 1)), steps=steps)
            self.rolled += self.K * steps
            out.append(res.t_reach[: len(part)])
        return np.concatenate(out) if out else np.zeros(0)

    def exchange(self, x0: Sequence[float], index: int, pool: Sequence[np.ndarray],
                 own: Optional["PlannedState"]) -> "PlannedState":
        """``own`` (this state's result), or the shortest of ``pool`` (other states' sequences)
        that reaches sooner from ``x0``."""
        x0 = np.asarray(x0, dtype=np.float64).ravel()
        start = time.perf_counter()
        best = own.steps if own is not None and own.steps is not None else None
        steps = self.deadline if best is None else best - 1
        if steps < 1 or not len(pool) or not np.all(np.isfinite(x0)):
            return own if own is not None else PlannedState(index, x0, None, "not_found", False)
        t = self.try_sequences(x0, pool, steps)
        k = int(np.argmin(t))
        base = own if own is not None else PlannedState(index, x0, None, "not_found", False)
        if not np.isfinite(t[k]):
            return base
        n = int(t[k])
        return replace(base, steps=n, status="solved", actions=np.asarray(pool[k], float).reshape(-1, self.m)[:n],
                       source="another state", rollouts=base.rollouts + len(pool),
                       seconds=base.seconds + time.perf_counter() - start)

    def descend(self, x0: np.ndarray, z0: np.ndarray, iterations: int = 60, horizon: Optional[int] = None,
                rollouts: float = math.inf, until: float = math.inf) -> tuple[float, Optional[np.ndarray], int]:
        """A local search from the knots ``z0``: L-BFGS-B on the terminal cost at ``horizon``
        (default the deadline), its gradient from central differences of the knots before it all
        at once (one batch of ``2 knots m + 1`` rollouts). For the pilot, when sampling around
        "do nothing" finds no way (moving first takes the swimmer away from its goal), and to
        shorten what it found. Returns ``(steps, knots, rollouts)`` of the first candidate that
        reached within ``horizon`` (``inf, None`` if none); it stops once it has spent ``rollouts``
        or the clock passes ``until`` (:meth:`now`)."""
        import scipy.optimize

        h = self.deadline if horizon is None else max(1, min(int(horizon), self.deadline))
        live = min(self.knots, -(-h // self.budget.hold))  # the knots that act before the horizon
        D = live * self.m
        if 2 * D + 1 > self.K:
            return math.inf, None, 0
        eps = 1e-3
        z0 = np.clip(np.asarray(z0, float).reshape(self.knots, self.m), -1, 1)
        found: list = [math.inf, None]
        used = [0]
        basis = np.eye(D)

        def f_and_g(flat: np.ndarray):
            head = np.concatenate([flat[None], flat[None] + eps * basis, flat[None] - eps * basis])
            zs = np.repeat(z0[None], len(head), axis=0)
            zs[:, :live] = head.reshape(-1, live, self.m)
            t_reach, cost = self.evaluate(x0, zs, h, terminal=True)
            used[0] += len(zs)
            k = int(np.argmin(t_reach))
            if t_reach[k] < found[0]:
                found[0], found[1] = float(t_reach[k]), zs[k].copy()
            g = (cost[1: D + 1] - cost[D + 1:]) / (2 * eps)
            if found[1] is not None or used[0] >= rollouts or self.now() > until:
                raise StopIteration
            return float(cost[0]), g

        try:
            scipy.optimize.minimize(f_and_g, z0[:live].ravel(), jac=True, method="L-BFGS-B",
                                    bounds=[(-1.0, 1.0)] * D, options={"maxiter": int(iterations)})
        except StopIteration:
            pass
        return found[0], found[1], used[0]

    def shorten(self, x0: np.ndarray, actions: np.ndarray, deadline: float, iterations: int = 60,
                rollouts: float = math.inf) -> tuple[list[np.ndarray], int]:
        """Shorter and shorter sequences from ``x0``, starting from ``actions`` (which reaches
        in ``len(actions)`` steps): the sequence compressed in time to a tenth fewer steps (a
        faster stroke is the natural guess for arriving sooner), then :meth:`descend` at that
        horizon; a step at a time once a tenth fails, until one step fewer fails or the clock
        (``deadline``, :meth:`now`) or the ``rollouts`` run out. Returns the
        sequences found, longest first, and the rollouts spent."""
        out, used = [np.asarray(actions, float).reshape(-1, self.m)], 0
        cut = max(1, len(out[0]) // 10)
        while len(out[-1]) > 1 and self.now() < deadline and used < rollouts:
            cur = out[-1]
            h = max(1, len(cur) - cut)
            squeezed = cur[np.floor(np.arange(h) * len(cur) / h).astype(int)]
            t, z, spent = self.descend(x0, self._to_knots(squeezed), iterations, horizon=h, rollouts=rollouts - used,
                                       until=deadline)
            used += spent
            if z is not None:
                out.append(self.actions(z[None])[0, : int(t)])
            elif cut > 1:
                cut = 1
            else:
                break
        return out, used

    def cost(self, t_reach: np.ndarray, rho: np.ndarray, failed: np.ndarray, terminal: bool) -> np.ndarray:
        """A candidate's cost (module docstring): its first hitting step where it reaches, else
        the steps plus ``W`` times how far ``asap`` is from holding (relative to the initial
        state) — at the last step (``terminal``), or at the best step — plus ``W`` on a failure."""
        W = self.weight * self.deadline
        with np.errstate(invalid="ignore", over="ignore"):
            v = np.maximum(0.0, -rho)
            v0 = np.where(np.isfinite(v[:, :1]) & (v[:, :1] > 0), v[:, :1], 1.0)
            soft = np.arange(rho.shape[1])[None, :] + W * (v / v0)
        soft = np.where(np.isnan(soft), np.inf, soft)
        if terminal:  # the last step before any failure (or the end)
            last = np.where(np.isnan(rho), -1, np.arange(rho.shape[1])[None, :]).argmax(axis=1)
            c = soft[np.arange(len(soft)), last] + (rho.shape[1] - 1 - last)
        else:  # step 0 is every candidate's: no information
            c = np.min(soft[:, 1:], axis=1) if soft.shape[1] > 1 else soft[:, 0]
        c = np.where(failed, c + W, c)
        c = np.where(np.isfinite(t_reach), np.minimum(c, t_reach), c)
        return np.where(np.isfinite(c), c, 1e6 * W)

    # ------------------------------------------------------------------ search
    def periodic(self, rng: np.random.Generator, count: int) -> np.ndarray:
        """``count`` periodic candidates (knots ``[count, knots, m]``, normalised units): one
        period per candidate (log-uniform from two knots to twice the deadline, so that the
        actions are coordinated), per action a phase, an amplitude and an offset, a sine or a
        square wave (bang-bang at full amplitude), and a step after which the actions rest at the
        centre of the box (a stroke, then a glide). Locomotion needs such coordinated periodic
        actions, which Gaussian noise around "do nothing" almost never produces."""
        m, n = self.m, int(count)
        knots = np.arange(self.knots)[None, :, None]
        period = np.exp(rng.uniform(math.log(2.0), math.log(2.0 * self.knots), (n, 1, 1)))
        phase = rng.uniform(0.0, 2 * math.pi, (n, 1, m))
        amp = rng.uniform(0.0, 1.0, (n, 1, m))
        offset = rng.uniform(-1.0, 1.0, (n, 1, m)) * (1.0 - amp)
        wave = np.sin(2 * math.pi * knots / period + phase)
        wave = np.where(rng.random((n, 1, 1)) < 0.5, np.sign(wave), wave)
        until = rng.integers(1, self.knots + 1, (n, 1, 1))
        return np.where(knots < until, np.clip(offset + amp * wave, -1.0, 1.0), 0.0)

    def switching(self, rng: np.random.Generator, count: int) -> np.ndarray:
        """``count`` bang-bang candidates (knots ``[count, knots, m]``, normalised units): per
        action a few switches (none to four) at random knots between the corners of its range,
        a quarter of the segments at a random level instead. Minimum-time plans are often
        bang-bang with a few switches (a manoeuvre: back up turning one way, then drive on
        turning the other), which neither noise around a mean nor a periodic wave produces."""
        m, n, k = self.m, int(count), self.knots
        switches = rng.integers(0, 5, (n, m))
        at = np.sort(rng.integers(1, max(2, k), (n, m, 4)), axis=2)
        at = np.where(np.arange(4)[None, None, :] < switches[:, :, None], at, k + 1)
        segment = (np.arange(k)[None, None, :, None] >= at[:, :, None, :]).sum(axis=3)  # [n, m, knots]
        sign = np.where(rng.random((n, m, 1)) < 0.5, -1.0, 1.0) * np.where(segment % 2 == 0, 1.0, -1.0)
        level = np.take_along_axis(rng.uniform(-1, 1, (n, m, 5)), segment, axis=2)
        z = np.where(np.take_along_axis(rng.random((n, m, 5)), segment, axis=2) < 0.25, level, sign)
        return z.transpose(0, 2, 1)

    def ranked_periodic(self, x0: np.ndarray, rng: np.random.Generator, batches: int) -> tuple[np.ndarray, int]:
        """``batches`` batches of :meth:`periodic` candidates rolled out from ``x0``, cheapest
        first (terminal cost: reaching ones first, by their steps), and the rollouts spent."""
        z = self.periodic(rng, self.K * max(1, int(batches)))
        cost = np.concatenate([self.evaluate(x0, z[at: at + self.K], self.deadline, terminal=True)[1]
                               for at in range(0, len(z), self.K)])
        return z[np.argsort(cost, kind="stable")], len(z)

    def _fixed(self, warm: Sequence[np.ndarray]) -> np.ndarray:
        """Candidates of the first population: constant actions at the centre and the corners of
        the action box (bang-bang), and the warm starts given (as knots), each with its last
        action held after its end and at rest there (a stroke that ends in a glide)."""
        m = self.m
        corners = np.array(np.meshgrid(*[[-1.0, 1.0]] * m, indexing="ij")).reshape(m, -1).T
        fixed = [np.zeros((1, m))] + [c[None, :] for c in corners[: max(0, self.K // 8 - 1)]]
        z = [np.broadcast_to(f, (self.knots, m))[None] for f in fixed]
        z += [self._to_knots(w, rest)[None] for w in warm for rest in (False, True)]
        return np.concatenate(z)[: self.K // 2]

    def _population(self, kept: np.ndarray, mu: np.ndarray, sigma: np.ndarray,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``kept`` candidates, then fresh ones from the islands' Gaussians in turn; each
        candidate's island (the kept ones: the island of the nearest mean)."""
        R, K = len(mu), self.K
        fresh_island = np.arange(K - len(kept)) % R
        fresh = mu[fresh_island] + sigma[fresh_island] * rng.standard_normal((K - len(kept),) + mu.shape[1:])
        z = np.concatenate([kept, np.clip(fresh, -1.5, 1.5)])
        if R == 1 or not len(kept):
            return z, np.concatenate([np.zeros(len(kept), dtype=int), fresh_island])
        d = ((kept[:, None] - mu[None]) ** 2).sum(axis=(2, 3))
        return z, np.concatenate([np.argmin(d, axis=1), fresh_island])

    def _to_knots(self, actions: np.ndarray, rest: bool = False) -> np.ndarray:
        """An action sequence (any length) as knots in normalised units, the last action held
        after its end (``rest``: the centre of the action box instead)."""
        a = np.asarray(actions, dtype=np.float64).reshape(-1, self.m)
        centre = np.zeros((1, self.m)) + (self.low + self.high) / 2
        if len(a) == 0:
            a = centre
        tail = centre if rest else a[-1:]
        full = np.concatenate([a, np.repeat(tail, max(0, self.deadline - len(a)), axis=0)])[: self.deadline]
        z = 2.0 * (full - self.low) / np.where(self.high > self.low, self.high - self.low, 1.0) - 1.0
        return z[:: self.budget.hold][: self.knots]

    def _shifted(self, z: np.ndarray, steps: int, rng: np.random.Generator) -> np.ndarray:
        """The sequence ``z`` with one knot before step ``steps`` removed (the rest moved one knot
        earlier): the natural candidates for arriving earlier, as in a bang-bang plan whose phase
        is one step shorter. At most a quarter of the population, the knots chosen at random."""
        last = min(self.knots, -(-steps // self.budget.hold))
        js = np.arange(last)
        if len(js) > self.K // 4:
            js = np.sort(rng.choice(js, self.K // 4, replace=False))
        if not len(js):
            return np.zeros((0,) + z.shape)
        return np.stack([np.concatenate([z[:j], z[j + 1:], z[-1:]]) for j in js])

    def plan(self, x0: Sequence[float], index: int = 0, warm: Sequence[np.ndarray] = (),
             iterations: Optional[int] = None, islands: int = 1) -> "PlannedState":
        """The fewest steps found from ``x0`` (the planner's sequence, not yet replayed).

        ``warm``: action sequences to try first (another state's, for instance); ``iterations``:
        instead of the budget's; ``islands``: populations searched side by side until one
        reaches (one at the centre of the action box, the others around random sequences), for
        dynamics where doing little is a local optimum (the pilot of
        :func:`~asap_dsl.backends.oracle.planning.plan_states`)."""
        start, begun = time.perf_counter(), self.now()
        b = self.budget
        x0 = np.asarray(x0, dtype=np.float64).ravel()
        if x0.shape != (self.n,) or not np.all(np.isfinite(x0)):
            return PlannedState(index, x0, None, "nan", False, seconds=time.perf_counter() - start)
        rng = state_seed(self.seed, x0)
        self.trace: list = []  # (steps rolled out, cheapest cost, best steps, mean spread) per iteration
        K, shape = self.K, (self.knots, self.m)
        # exploration: islands, one at the centre of the action box, the others at random sequences
        R = max(1, min(int(islands), K // 8))
        mu = np.concatenate([np.zeros((1,) + shape), rng.uniform(-1, 1, (R - 1,) + shape)])
        sigma = np.full((R,) + shape, b.sigma)
        first = np.concatenate([self._fixed(warm), self.periodic(rng, K // 4)])[: K // 2]
        z, island = self._population(first, mu, sigma, rng)
        best_t, best_z = math.inf, None
        rollouts = iters = 0
        timed_out = False
        archive: list = []
        for it in range(b.iterations if iterations is None else int(iterations)):
            if self.now() - begun > self.time_limit:
                timed_out = True
                break
            found = math.isfinite(best_t)
            steps = int(best_t) - 1 if found else self.deadline
            if steps < 1:
                break  # reached at step 1 (or 0): nothing is earlier
            t_reach, cost = self.evaluate(x0, z, steps, terminal=not found)
            rollouts += len(z)
            iters += 1
            k = int(np.argmin(t_reach))
            if t_reach[k] < best_t:
                best_t, best_z = float(t_reach[k]), z[k].copy()
                if not found:  # one population around it from now on
                    R, island = 1, np.zeros(K, dtype=int)
                    mu, sigma = best_z[None].copy(), np.full((1,) + shape, b.refine_sigma)
            self.trace.append((steps, float(cost.min()), best_t, float(sigma.mean())))
            if not found:  # the cheapest of each batch: where the descents start if none reaches
                top = np.argsort(cost, kind="stable")[:4]
                archive.extend(zip(cost[top].tolist(), z[top]))
            kept = []
            for r in range(R):
                members = np.flatnonzero(island == r)
                order = members[np.argsort(cost[members], kind="stable")]
                n_elite = max(4, int(round(b.elite * len(members))))
                elite = z[order[:n_elite]]
                if b.method == "cem":
                    new_mu, new_sigma = elite.mean(axis=0), elite.std(axis=0)
                elif b.method == "mppi":
                    c = cost[members] - cost[order[0]]
                    lam = max(1e-9, float(np.mean(cost[order[:n_elite]] - cost[order[0]])) or 1.0)
                    w = np.exp(-c / lam)
                    new_mu, new_sigma = np.tensordot(w / w.sum(), z[members], axes=1), sigma[r]
                else:  # predictive sampling: the best is the nominal
                    new_mu, new_sigma = z[order[0]], sigma[r]
                mu[r] = b.smoothing * mu[r] + (1 - b.smoothing) * new_mu
                sigma[r] = np.maximum(b.smoothing * sigma[r] + (1 - b.smoothing) * new_sigma, b.floor)
                kept.append(elite[: max(1, int(round(b.keep * n_elite)))])
            kept = np.concatenate(kept)
            if best_z is not None:
                kept = np.concatenate([best_z[None], kept, self._shifted(best_z, int(best_t), rng)])[: K // 2]
            z, island = self._population(kept, mu, sigma, rng)
        U = None if best_z is None else self.actions(best_z[None])[0, : int(best_t)]
        if b.polish > 0 and not timed_out:
            U, used = self.polish(x0, U, archive, rng, b.polish * K * b.iterations, begun + self.time_limit)
            rollouts += used
            timed_out = U is None and self.now() - begun > self.time_limit
        seconds = time.perf_counter() - start
        if U is None:
            return PlannedState(index, x0, None, "timeout" if timed_out else "not_found", False, seconds=seconds,
                                rollouts=rollouts, iterations=iters)
        return PlannedState(index, x0, len(U), "solved", False, actions=U, seconds=seconds, rollouts=rollouts,
                            iterations=iters)

    def polish(self, x0: np.ndarray, actions: Optional[np.ndarray], archive: list, rng: np.random.Generator,
               rollouts: float, deadline: float) -> tuple[Optional[np.ndarray], int]:
        """After the sampling, within ``rollouts`` and the clock (``deadline``): where nothing
        reached, :meth:`descend` from the cheapest distinct candidates the sampling saw
        (``archive``: ``(cost, knots)``), then from the cheapest of fresh proposals (bang-bang
        with a few switches, periodic, uniform noise), until one reaches; then
        :meth:`shorten` what reached, for at most ``shorten_seconds`` of the clock (on a costly
        simulator, the swimmer's, shortening a found sequence takes many descents for a step or
        two; finding one where nothing reached keeps the whole budget). Sampling stalls on long
        manoeuvres (the bicycle turning round below its goal) where a descent from near them
        arrives; once a sequence reaches, squeezing it in time and descending at the shorter
        horizon finds the earlier arrivals that mutating single knots misses. Returns the actions (None: none reached) and the
        rollouts spent."""
        used, n = 0, self.budget.descents
        if actions is None:
            archive = sorted(archive, key=lambda e: e[0])
            starts: list = []
            for _, z in archive:  # distinct: some knot differs by more than a quarter of the box
                if len(starts) < n and all(np.abs(z - s).max() > 0.5 for s in starts):
                    starts.append(z)
            B = max(1, n // 2) * self.K
            fresh = np.concatenate([self.switching(rng, B), self.periodic(rng, B),
                                    rng.uniform(-1.0, 1.0, (B, self.knots, self.m))])
            if used + len(fresh) <= rollouts:
                cost = np.concatenate([self.evaluate(x0, fresh[at: at + self.K], self.deadline, terminal=True)[1]
                                       for at in range(0, len(fresh), self.K)])
                used += len(fresh)
                starts += list(fresh[np.argsort(cost, kind="stable")[:n]])
            for z0 in starts:
                if used >= rollouts or self.now() > deadline:
                    break
                t, z, spent = self.descend(x0, z0, 100, rollouts=rollouts - used, until=deadline)
                used += spent
                if z is not None:
                    actions = self.actions(z[None])[0, : int(t)]
                    break
            if actions is None:
                return None, used
        until = min(deadline, self.now() + self.budget.shorten_seconds)
        found, spent = self.shorten(x0, actions, until, rollouts=max(0.0, rollouts - used))
        return found[-1], used + spent
