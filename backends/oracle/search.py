"""The oracle's search for one task: per initial state, the smallest horizon N at which some
action sequence fulfils the task, verified by replay.

* N-search: minimum time is not monotone in N (the goal need not be invariant), so there is no
  bisection: N goes upward from a lower bound (:class:`~asap_dsl.backends.oracle.bounds.HorizonBounds`)
  to the deadline and the first feasible N is the answer. For linear dynamics the lower bound is a
  support-function test (the goal must not be separated from the reachable set of step N by the
  hyperplane normal to the direction from the free response to the goal, ignoring the state space
  and ``avoid``: a relaxation, so the bound is sound and skips most infeasible N without a solve).
  For non-linear dynamics it is interval reachability: the simulator's integrator evaluated in
  interval arithmetic over the whole action box, intersected with the state space each step
  (trajectories must stay in it), widened for rounding; N below the first step whose box can meet
  ``asap`` is infeasible for every action sequence (a proof, not a local search). A box that
  leaves the state space proves the deadline out of reach without a solve.
* At each N, every alternative of ``asap`` is one NLP
  (:class:`~asap_dsl.backends.oracle.nlp.ShootingProblems`), warm-started from the solution of the
  previous (nearest) state at the same N, or from this state's solution at N-1.
* Multi-start: when the NLP at N ends with a positive slack, up to ``restarts`` (default
  :data:`RESTARTS` for non-linear dynamics, 0 for linear ones) other initial guesses are tried
  before N is declared infeasible — in :data:`~asap_dsl.backends.oracle.nlp.START_ORDER`: this
  state's solution at N-1 shifted, constant-action rollouts (centre of the action box, then
  bang-bang on the first action), the straight line from x0 to the goal's centre — and the best
  is kept as the next warm start. Deterministic; the extra solves are counted (``restarts``).
* Every solution, feasible or not, is rolled out (the CasADi step: the same discretisation in one
  compiled call) and its shortest prefix that fulfils the task is taken (a solution at N with
  positive slack may pass through the goal earlier).
* Labels: ``exact`` when the feasibility problem of every N is convex — linear dynamics (an
  ``ode`` with ``integrator exact`` or any integrator of a linear ODE, or a linear ``map``), goal
  literals that are balls/boxes over linear coordinates, no ``avoid``: then IPOPT's optimum is
  global and "not feasible at N" is a proof. Everything else is ``local``: IPOPT's local optimum,
  so the reported minimum is an upper bound on the true minimum time from that state.
* Verification: the action sequence is replayed through :func:`asap_dsl.dynamics.numpy_step` (the
  simulator's own step) and checked with the task's own formulas; a state is ``verified`` only if
  the replay reaches ``asap`` at step N, never satisfies ``avoid`` and never leaves the state space.
"""

from __future__ import annotations

import itertools
import math
import time
from typing import Callable, Optional, Sequence

import numpy as np

from asap_dsl.dynamics import casadi_step, numpy_step
from asap_dsl.expr import degree
from asap_dsl.stl import ir, offline

from .bounds import HorizonBounds, coords_linear
from .clock import WorkClock
from .goals import Goals, OracleUnsupported
from .nlp import IPOPT_OPTIONS, ShootingProblems
from .results import StateResult

__all__ = ["FEASIBLE_TOL", "RESTARTS", "STATE_TIME_LIMIT", "Oracle", "nearest_neighbour_order"]

#: An NLP optimum (sum of slacks) at most this is "feasible" (then the replay decides).
FEASIBLE_TOL = 1e-7
#: Extra initial guesses tried (local problems only) before a horizon is declared infeasible.
RESTARTS = 1
#: Seconds of horizon search per initial state before it is reported as ``timeout`` (a deadline
#: of 1,000,000 steps with an unreachable goal would otherwise search for days).
STATE_TIME_LIMIT = 120.0
#: Under a simulated clock, the wall clock still ends a state's search after this many times its
#: limit: a guard against a hung solve, never reached by a search the clock prices right.
WALL_GUARD = 10.0


class Oracle:
    """Minimum-time oracle for one task of a program (built once, solved for many states).

    :param prog: the program (:func:`asap_dsl.load`); its system must be an ``ode`` or a ``map``.
    :param task: the task's name (default: the program's only or first task, as ``prog.task``).
    :param ipopt_options: ``nlpsol`` options over :data:`~asap_dsl.backends.oracle.nlp.IPOPT_OPTIONS`.
    :param restarts: extra initial guesses per horizon before it is declared infeasible (default
        :data:`RESTARTS` for non-linear dynamics, 0 for linear ones).
    :param interval_bound: start the N-search of non-linear systems at the interval lower bound.
    :param time_limit: seconds of search per state (each IPOPT solve is capped by it too).
    :param clock: read ``time_limit`` on this simulated clock (:mod:`.clock`) instead of the wall
        clock, so that what is found is the same on every machine (a training run's
        demonstrations); the wall clock then only ends a state after :data:`WALL_GUARD` times the
        limit (a solve that hangs).
    :raises OracleUnsupported: a black-box system, or a task outside what the oracle solves.
    :raises KeyError: an unknown task.
    :raises ValueError: a time limit that is not a positive number.
    """

    def __init__(self, prog, task: Optional[str] = None, ipopt_options: Optional[dict] = None,
                 restarts: Optional[int] = None, interval_bound: bool = True,
                 time_limit: float = STATE_TIME_LIMIT, clock: Optional[WorkClock] = None):
        self.prog = prog
        self.clock = clock
        self.system = sys_ = prog.system
        if sys_.kind == "simulator":
            raise OracleUnsupported(
                f"system {sys_.name} is a black-box simulator ({sys_.simulator}): no known dynamics: "
                "the oracle needs an ode or map system")
        t = prog.task(task)
        self.task = t
        self.task_name = t.model.name
        self.deadline = int(t.model.deadline)
        self.tolerances = tuple(int(v) for v in t.model.tolerances)
        self.regions = prog.regions
        self.goals = Goals(t.model, self.regions)  # unsupported parts fail here, up front
        self.n, self.m = sys_.n_state, sys_.n_action
        self.step_np = numpy_step(sys_)
        self._step_ca = step_ca = casadi_step(sys_)
        self._rollouts: dict[int, object] = {}  # N -> the step's N-fold rollout (CasADi mapaccum)
        if not (time_limit > 0 and math.isfinite(time_limit)):
            raise ValueError(f"the time limit per state must be a positive number of seconds; got {time_limit}")
        self.time_limit = float(time_limit)
        self.wall_limit = self.time_limit * (1.0 if clock is None else WALL_GUARD)
        options = dict(IPOPT_OPTIONS, **{"ipopt.max_cpu_time": self.wall_limit}, **(ipopt_options or {}))
        self.low, self.high = sys_.state_low, sys_.state_high
        self.ulow, self.uhigh = sys_.action_low, sys_.action_high
        self.bounds = HorizonBounds(sys_, self.regions, self.goals.regions_now, self.deadline, self.step_np,
                                    interval_bound)
        self.linear = self.bounds.linear
        literals = [lit for c in self.goals.widest for lit in c]
        self.convex = (self.linear and self.goals.safe is None
                       and all(lit.positive and self._literal_convex(lit.atom) for lit in literals))
        self.label = "exact" if self.convex else "local"
        # default: restarts for non-linear dynamics only. With linear dynamics the only
        # non-convexity is in `avoid` / the goal, and there the warm-started search already agrees
        # (dc_motor reach_avoid, 1000 states: 8229 extra solves, 3.5x the time, no state changed)
        self.restarts = (0 if self.linear else RESTARTS) if restarts is None else max(0, int(restarts))
        self.problems = ShootingProblems(sys_, self.regions, self.goals, step_ca, self.step_np, options)

    def _literal_convex(self, atom: ir.Atom) -> bool:
        """Holding is a convex condition when linear: a region over linear coordinates, an affine
        comparison."""
        if atom.region is not None:
            return coords_linear(self.system, self.regions[atom.region])
        return degree(atom.margin, self.system.symbols) <= 1

    def lower_bound(self, x0: np.ndarray, until: float = math.inf) -> int:
        """Where the N-search of ``x0`` starts (:meth:`HorizonBounds.lower_bound`)."""
        return self.bounds.lower_bound(x0, until)

    # ------------------------------------------------------------------ replay
    def replay(self, x0: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, bool]:
        """Roll ``actions`` out with the simulator's step; ``(trajectory [N+1, n], passes)``."""
        x = np.asarray(x0, float)[None, :]
        traj = [x[0]]
        with np.errstate(all="ignore"):  # a diverging replay becomes inf/NaN and fails the check
            for u in np.asarray(actions, float).reshape(-1, self.m):
                x = self.step_np(x, np.clip(u, self.ulow, self.uhigh)[None, :])
                traj.append(np.asarray(x[0], float))
        tr = np.asarray(traj)
        return tr, self.trajectory_ok(tr)

    def fulfilled(self, tr: np.ndarray) -> np.ndarray:
        """Per step k of the trajectory ``[N+1, n]``, whether its first k steps ``tr[:k + 1]``
        fulfil the task: finite up to k, inside the state space at steps 1..k, ``asap`` at k,
        ``avoid`` at none of steps 1..k (``[N+1]`` booleans).

        One pass: ``asap``'s operators look only backwards, so its value at step k on the whole
        trajectory is its value on the prefix (the oracle's goals are built from such formulas
        alone, :mod:`.goals`)."""
        out = np.zeros(tr.shape[0], bool)
        finite = np.all(np.isfinite(tr), axis=1)
        good = tr.shape[0] if finite.all() else int(np.argmin(finite))  # steps before the first non-finite
        if good == 0:
            return out
        tr = tr[:good]
        ok = offline.satisfied(self.task.model.asap, tr[None])[0].astype(bool)
        ok[1:] &= np.logical_and.accumulate(np.all((tr[1:] >= self.low) & (tr[1:] <= self.high), axis=1))
        avoid = self.task.model.avoid
        if avoid is not None:
            ok[1:] &= ~np.logical_or.accumulate(offline.satisfied(avoid, tr[None])[0, 1:])
        out[:good] = ok
        return out

    def trajectory_ok(self, tr: np.ndarray) -> bool:
        """Whether the trajectory ``[N+1, n]`` fulfils the task at its last step (:meth:`fulfilled`)."""
        return bool(self.fulfilled(tr)[-1])

    def first_passing_prefix(self, x0: np.ndarray, actions: np.ndarray) -> Optional[int]:
        """The smallest k >= 1 such that the first k actions fulfil the task (replayed), or None."""
        tr, _ = self.replay(x0, actions)
        return self.passing_prefix(tr)

    def passing_prefix(self, tr: np.ndarray) -> Optional[int]:
        """The smallest k >= 1 such that the trajectory's first k steps fulfil the task
        (:meth:`fulfilled`), or None."""
        hits = np.flatnonzero(self.fulfilled(tr)[1:])
        return int(hits[0]) + 1 if hits.size else None

    def _rollout(self, x0: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """``actions`` rolled out from ``x0`` with the CasADi step: the trajectory ``[N+1, n]``.

        The same discretisation as :meth:`replay` in one compiled call (the numpy step costs
        milliseconds a state, and the search checks every solution's prefixes: a third of its
        time on attitude); the answer is verified by :meth:`replay` all the same."""
        U = np.clip(np.asarray(actions, float).reshape(-1, self.m), self.ulow, self.uhigh)
        N = U.shape[0]
        roll = self._rollouts.get(N)
        if roll is None:
            roll = self._rollouts[N] = self._step_ca.mapaccum(N)
        with np.errstate(all="ignore"):
            X = np.asarray(roll(np.asarray(x0, float), U.T)).reshape(self.n, N).T if N else np.zeros((0, self.n))
        return np.vstack([np.asarray(x0, float)[None, :], X])

    # ------------------------------------------------------------------ search
    def _try(self, N: int, x0: np.ndarray, own: dict[int, np.ndarray]):
        """Solve every alternative at N, with up to :attr:`restarts` extra initial guesses each
        while the optimum is positive. Returns ``(status, actions, failures, solves, restarts)``,
        status ok / no / failed. "ok" also when the replay of some solution's first k <= N
        actions already fulfils the task (then ``actions`` has k rows). ``own``: this state's
        solution per horizon so far (updated)."""
        nlp = self.problems
        failures = solves = extra = 0
        for j in range(len(self.goals.at(N))):
            best_w, best_obj = None, math.inf
            alts = itertools.islice(nlp.other_guesses(N, j, x0, own), self.restarts)
            for name, w0 in itertools.chain([("first", nlp.first_guess(N, j, x0, own))], alts):
                w, obj, clean = nlp.solve(N, j, x0, w0)
                solves += 1
                extra += name != "first"
                failures += not clean
                if w is None:
                    continue
                if obj < best_obj:
                    best_w, best_obj = w, obj
                U = nlp.actions(N, w)
                p = self.passing_prefix(self._rollout(x0, U))
                if obj <= FEASIBLE_TOL or p is not None:
                    # feasible (the replay in solve() judges it), or a prefix of the rollout
                    # already fulfils the task although the slack is positive
                    own[N] = w
                    nlp.remember(N, j, w)
                    return "ok", (U if p is None else U[:p]), failures, solves, extra
            if best_w is not None:
                own[N] = best_w
                nlp.remember(N, j, best_w)
        return ("failed" if failures else "no"), None, failures, solves, extra

    def solve(self, x0: Sequence[float], index: int = 0) -> StateResult:
        """The minimum number of steps from ``x0`` (see the module docstring); ``index`` is the
        result's index. Solver failures never raise."""
        start = time.perf_counter()
        begun = self.problems.work.copy()
        x0 = np.asarray(x0, float).ravel()
        if x0.shape != (self.n,) or not np.all(np.isfinite(x0)):
            return StateResult(index, x0, None, "nan", False, seconds=time.perf_counter() - start)
        tr0 = x0[None, :]
        if self.trajectory_ok(tr0):
            return StateResult(index, x0, 0, "solved", True, actions=np.zeros((0, self.m)),
                               trajectory=tr0, seconds=time.perf_counter() - start)
        lb = max(1, self.lower_bound(x0, until=start + self.wall_limit))
        failures = solves = restarts = 0
        own: dict[int, np.ndarray] = {}
        for N in range(lb, self.deadline + 1):
            if self._spent(start, begun) > self.time_limit or time.perf_counter() - start > self.wall_limit:
                return StateResult(index, x0, None, "timeout", False, failures, solves, lb,
                                   seconds=time.perf_counter() - start, restarts=restarts, horizon=N - 1)
            status, U, failed, used, extra = self._try(N, x0, own)
            solves += used
            restarts += extra
            failures += failed
            if status == "ok":
                tr, passes = self.replay(x0, U)
                if not np.all(np.isfinite(tr)):
                    return StateResult(index, x0, None, "nan", False, failures, solves, lb, restarts=restarts,
                                       seconds=time.perf_counter() - start)
                return StateResult(index, x0, U.shape[0], "solved", passes, failures, solves, lb, U, tr,
                                   time.perf_counter() - start, restarts=restarts)
        return StateResult(index, x0, None, "solver_failed" if failures else "infeasible", False, failures,
                           solves, lb, seconds=time.perf_counter() - start, restarts=restarts)

    def _spent(self, start: float, begun) -> float:
        """Seconds since ``start`` (``time.perf_counter``), or on the clock since the work ``begun``."""
        if self.clock is None:
            return time.perf_counter() - start
        return self.clock.seconds(self.problems.work.since(begun))

    def solve_many(self, states: np.ndarray, indices: Optional[Sequence[int]] = None,
                   progress: Optional[Callable[[int], None]] = None,
                   until: Optional[float] = None, budget: Optional[float] = None) -> list[StateResult]:
        """Solve ``states`` in nearest-neighbour order (warm starts), results in input order;
        ``indices``: the results' indices (default 0, 1, ...); ``progress(1)`` after each state.
        ``until``: a wall-clock time (``time.time()``) after which no state is begun; ``budget``:
        seconds on the oracle's clock after which none is begun; with either the results are the
        solved states' alone. Under a simulated clock the first state starts cold, so that the
        states' results do not depend on what this process solved before."""
        states = np.asarray(states, float).reshape(-1, self.n)
        idx = list(range(len(states))) if indices is None else list(indices)
        order = nearest_neighbour_order(states, self.system)
        out: list[Optional[StateResult]] = [None] * len(states)
        if self.clock is not None:
            self.problems.forget()
        start, begun = time.perf_counter(), self.problems.work.copy()
        for k in order:
            if until is not None and time.time() >= until:
                break
            if budget is not None and self._spent(start, begun) >= budget:
                break
            out[k] = self.solve(states[k], idx[k])
            if progress is not None:
                progress(1)
        partial = until is not None or budget is not None
        return [r for r in out if r is not None] if partial else out  # type: ignore[return-value]


def nearest_neighbour_order(states: np.ndarray, system) -> list[int]:
    """A greedy nearest-neighbour tour of the states (scaled by the init box), for warm starts."""
    n = len(states)
    if n == 0:
        return []
    width = np.where(system.init_high > system.init_low, system.init_high - system.init_low, 1.0)
    z = (states - system.init_low) / width
    z = np.where(np.isfinite(z), z, 0.0)
    left = np.ones(n, bool)
    cur = int(np.argmin(np.sum(z, axis=1)))
    order = [cur]
    left[cur] = False
    for _ in range(n - 1):
        d = np.sum((z - z[cur]) ** 2, axis=1)
        d[~left] = np.inf
        cur = int(np.argmin(d))
        order.append(cur)
        left[cur] = False
    return order
