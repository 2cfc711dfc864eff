"""The minimum-time oracle: the fewest steps in which *any* admissible policy can fulfil a task.

For a task whose ``asap`` is built from conditions on the state (regions ``in R`` and comparisons
such as ``x > 4``) with ``not``, ``and``, ``or``, ``->`` and the past operators ``historically``
and ``once`` over windows (unfolded into one condition per step of the window: a dwell
``historically[0, 2] in home`` constrains the last three states), and whose ``avoid`` is such a
condition without temporal operators, on a system with known dynamics (``ode`` or ``map``), the
oracle computes
for each initial state x0 the smallest N such that some action sequence within the action bounds
reaches ``asap`` at step N, with ``avoid`` false and the state inside the state space at steps
1..N, under the simulator's very discretisation (:func:`asap_dsl.dynamics.casadi_step`).

How
---
(The lower bounds on N are in :mod:`asap_dsl.backends.oracle.bounds`, the normal form of ``asap``
in :mod:`asap_dsl.backends.oracle.goals`, the results in :mod:`asap_dsl.backends.oracle.results`.)

* One NLP per (N, disjunct of ``asap`` in disjunctive normal form), built once with CasADi
  (multiple shooting: the states at steps 1..N are variables tied by ``x_k = step(x_{k-1},
  u_{k-1})``), solved by IPOPT through an ``nlpsol`` whose parameter is x0. The same NLP serves
  every initial state; it is warm-started from the solution of the previous (nearest) state at the
  same N, or from this state's solution at N-1.
* The NLP is *elastic*: the goal, the ``avoid`` constraints and the state-space bounds each get a
  non-negative slack, and the objective is the sum of slacks. It is therefore always feasible (no
  IPOPT infeasibility detection, which is slow and unreliable), and N is feasible exactly when
  the optimum is zero. Balls are squared distances (``|v-c|^2 <= (r-d)^2`` inside,
  ``>= (r+d)^2`` outside), boxes are linear sides; the goal is shrunk and ``avoid`` and the state
  space are grown by a tiny margin d so that the solution survives the replay.
* N-search: minimum time is not monotone in N (the goal need not be invariant), so there is no
  bisection: N goes upward from a lower bound to the deadline and the first feasible N is the
  answer. For linear dynamics the lower bound is a support-function test (the goal must not be
  separated from the reachable set of step N by the hyperplane normal to the direction from the
  free response to the goal, ignoring the state space and ``avoid``: a relaxation, so the bound is
  sound and skips most infeasible N without a solve). For non-linear dynamics it is interval
  reachability: the simulator's integrator evaluated in interval arithmetic over the whole action
  box, intersected with the state space each step (trajectories must stay in it), widened for
  rounding; N below the first step whose box can meet ``asap`` is infeasible for every action
  sequence (a proof, not a local search). A box that leaves the state space proves the deadline
  out of reach without a solve.
* Multi-start: when the NLP at N ends with a positive slack, up to ``restarts`` (default
  :data:`RESTARTS` for non-linear dynamics, 0 for linear ones) other initial guesses are tried
  before N is declared infeasible — in :attr:`Oracle.START_ORDER`: this state's solution at N-1
  shifted, constant-action rollouts (centre of the action box, then bang-bang on the first
  action), the straight line from x0 to the goal's centre — and the best is kept as the next
  warm start. Deterministic; the extra solves are counted (``restarts``).
* Every solution, feasible or not, is replayed and its shortest prefix that fulfils the task is
  taken (a solution at N with positive slack may pass through the goal earlier).
* Consistency: :func:`tighten` makes the local minima of tasks sharing ``asap`` consistent (a
  state's ``reach`` minimum cannot exceed its ``reach_avoid`` minimum), each adopted sequence
  verified by replay.
* Labels: ``exact`` when the feasibility problem of every N is convex — linear dynamics (an
  ``ode`` with ``integrator exact`` or any integrator of a linear ODE, or a linear ``map``), goal
  literals that are balls/boxes over linear coordinates, no ``avoid``: then IPOPT's optimum is
  global and "not feasible at N" is a proof. Everything else is ``local``: IPOPT's local optimum,
  so the reported minimum is an upper bound on the true minimum time from that state.
* Verification: the action sequence is replayed through :func:`asap_dsl.dynamics.numpy_step` (the
  simulator's own step) and checked with the task's own formulas; a state is ``verified`` only if
  the replay reaches ``asap`` at step N, never satisfies ``avoid`` and never leaves the state space.

Per-state statuses: ``solved`` (a minimum N found), ``infeasible`` (no N up to the deadline;
clean solves), ``solver_failed`` (no N found and IPOPT failed at some N), ``timeout`` (the
search used up its time, :data:`STATE_TIME_LIMIT` by default, before deciding: no N up to
``horizon``), ``nan`` (a non-finite initial state or dynamics). Solver failures never raise.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import replace
from typing import Any, Callable, Optional, Sequence

import numpy as np

from asap_dsl import ast
from asap_dsl.diagnostics import Span
from asap_dsl.dynamics import casadi_step, numpy_step
from asap_dsl.expr import casadi_namespace, compile_function, degree
from asap_dsl.sampling import EVAL_SEED, task_states
from asap_dsl.stl import ir, offline

from .bounds import HorizonBounds
from .goals import OracleUnsupported, _dnf, _flatten_and, _literals, _normal
from .results import OracleReport, StateResult

#: Margin by which the goal is shrunk and ``avoid`` / the state space are kept clear in the NLP.
MARGIN = 1e-6
#: An NLP optimum (sum of slacks) at most this is "feasible" (then the replay decides).
FEASIBLE_TOL = 1e-7
#: Solver return statuses that count as a clean solve.
GOOD_STATUSES = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
#: Extra initial guesses tried (local problems only) before a horizon is declared infeasible.
RESTARTS = 1
#: Seconds of horizon search per initial state before it is reported as ``timeout`` (a deadline
#: of 1,000,000 steps with an unreachable goal would otherwise search for days).
STATE_TIME_LIMIT = 120.0

IPOPT_OPTIONS = {
    "ipopt.print_level": 0,
    "ipopt.sb": "yes",
    "print_time": False,
    "ipopt.tol": 1e-9,
    "ipopt.constr_viol_tol": 1e-9,
    "ipopt.acceptable_tol": 1e-7,
    "ipopt.max_iter": 400,
    "ipopt.mu_strategy": "adaptive",
}


class Oracle(HorizonBounds):
    """Minimum-time oracle for one task of a program (built once, solved for many states)."""

    def __init__(self, prog, task: Optional[str] = None, ipopt_options: Optional[dict] = None,
                 restarts: Optional[int] = None, interval_bound: bool = True,
                 time_limit: float = STATE_TIME_LIMIT):
        """``restarts``: extra initial guesses per horizon before it is declared infeasible
        (default :data:`RESTARTS` for non-linear dynamics, 0 for linear ones);
        ``interval_bound``: start the N-search of non-linear systems at the interval lower bound;
        ``time_limit``: seconds of search per state (each IPOPT solve is capped by it too)."""
        import casadi as ca

        self.ca = ca
        self.prog = prog
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
        self._dnf_at: dict[int, list] = {}
        widest = self.goal_dnf_at(self.deadline)  # the most alternatives: unsupported parts fail here, up front
        self.safe_nnf = None if t.model.avoid is None else _normal(t.model.avoid, None, positive=False)
        for atom, _, _ in [lit for c in widest for lit in c] + (_literals(self.safe_nnf) if self.safe_nnf else []):
            if atom.region is not None and atom.region not in self.regions:
                raise OracleUnsupported(f"unknown region '{atom.region}'")
        # What the lower bounds test (a relaxation, hence sound): per alternative, its region
        # literals at step N itself. Alternatives at a smaller N are these, or weaker (cut windows).
        self.goal_now = [[(a.region, pos) for a, pos, back in conj if back == 0 and a.region is not None]
                         for conj in widest]
        self.n, self.m = sys_.n_state, sys_.n_action
        self.step_np = numpy_step(sys_)
        self.step_ca = casadi_step(sys_)
        if not (time_limit > 0 and math.isfinite(time_limit)):
            raise ValueError(f"the time limit per state must be a positive number of seconds; got {time_limit}")
        self.time_limit = float(time_limit)
        self.opts = dict(IPOPT_OPTIONS, **{"ipopt.max_cpu_time": self.time_limit}, **(ipopt_options or {}))
        self.low, self.high = sys_.state_low, sys_.state_high
        self.ulow, self.uhigh = sys_.action_low, sys_.action_high
        self.linear = self._is_linear()
        literals = [lit for c in widest for lit in c]
        self.convex = (self.linear and self.safe_nnf is None
                       and all(pos and self._literal_convex(atom) for atom, pos, _ in literals))
        self.label = "exact" if self.convex else "local"
        # default: restarts for non-linear dynamics only. With linear dynamics the only
        # non-convexity is in `avoid` / the goal, and there the warm-started search already agrees
        # (dc_motor reach_avoid, 1000 states: 8229 extra solves, 3.5x the time, no state changed)
        self.restarts = (0 if self.linear else RESTARTS) if restarts is None else max(0, int(restarts))
        self.interval_bound = bool(interval_bound)
        self._interval_fns: Optional[tuple] = None
        self._coords_fn: dict[Any, Any] = {}  # region name, or id of a comparison margin -> compiled
        self._solvers: dict[tuple[int, int], Any] = {}
        self._warm: dict[tuple[int, int], dict] = {}   # last solution per (N, disjunct)
        self._affine = self._affine_step() if self.linear else None

    def goal_dnf_at(self, N: int) -> list[list[tuple]]:
        """The alternatives of ``asap`` judged at step N (conjunctions of (atom, positive, back))."""
        if N not in self._dnf_at:
            self._dnf_at[N] = _dnf(_normal(self.task.model.asap, N))
        return self._dnf_at[N]

    def _literal_convex(self, atom: ir.Atom) -> bool:
        """Holding is a convex condition when linear: a region over linear coordinates, an affine
        comparison."""
        if atom.region is not None:
            return self._coords_linear(atom.region)
        return degree(atom.margin, self.system.symbols) <= 1

    # ------------------------------------------------------------------ NLP
    def _coords(self, region: str):
        if region not in self._coords_fn:
            R = self.regions[region]
            self._coords_fn[region] = compile_function([ast.Name(c, Span()) for c in R.coords],
                                                       self.system.symbols, casadi_namespace())
        return self._coords_fn[region]

    def _literal_exprs(self, atom: ir.Atom, positive: bool, x) -> list:
        """Expressions that are all >= 0 exactly when the literal holds with margin."""
        ca = self.ca
        if atom.region is None:  # a comparison: its margin (positive when it holds)
            key = id(atom.margin)
            if key not in self._coords_fn:
                self._coords_fn[key] = (atom, compile_function([atom.margin], self.system.symbols, casadi_namespace()))
            margin = self._coords_fn[key][1]([x[i] for i in range(self.n)], ())[0]
            return [margin - MARGIN] if positive else [-margin - MARGIN]
        region = atom.region
        R = self.regions[region]
        v = ca.vertcat(*self._coords(region)([x[i] for i in range(self.n)], ()))
        if R.kind == "ball":
            d2 = ca.sumsqr(v - ca.DM(list(R.centre)))
            if positive:
                return [(R.radius - MARGIN) ** 2 - d2]
            return [d2 - (R.radius + MARGIN) ** 2]
        lo, hi = ca.DM(list(R.low)), ca.DM(list(R.high))
        if positive:
            return [v - lo - MARGIN, hi - v - MARGIN]  # vector expressions, each entry >= 0
        k = v.shape[0]
        out = lo[0] - v[0] - MARGIN
        for i in range(k):
            out = ca.fmax(out, ca.fmax(lo[i] - v[i] - MARGIN, v[i] - hi[i] - MARGIN))
        return [out]

    def _formula_expr(self, f, x):
        """One scalar expression >= 0 when the normalised formula holds (fmin/fmax)."""
        ca = self.ca
        kind = f[0]
        if kind == "const":
            return ca.DM(1.0 if f[1] else -1.0)
        if kind == "lit":
            parts = self._literal_exprs(f[1], f[2], x)  # (an `avoid` literal: no step back)
            flat = [p[i] for p in parts for i in range(p.shape[0])]
            out = flat[0]
            for p in flat[1:]:
                out = ca.fmin(out, p)
            return out
        subs = [self._formula_expr(g, x) for g in f[1]]
        out = subs[0]
        for s in subs[1:]:
            out = ca.fmin(out, s) if kind == "and" else ca.fmax(out, s)
        return out

    def _safe_exprs(self, x) -> list:
        f = self.safe_nnf
        if f[0] == "lit":
            return self._literal_exprs(f[1], f[2], x)
        if f[0] == "and" and all(g[0] == "lit" for g in _flatten_and(f)):
            return [e for g in _flatten_and(f) for e in self._literal_exprs(g[1], g[2], x)]
        return [self._formula_expr(f, x)]

    def _solver(self, N: int, j: int):
        key = (N, j)
        if key in self._solvers:
            return self._solvers[key]
        ca = self.ca
        n, m = self.n, self.m
        x0 = ca.SX.sym("x0", n)
        X = ca.SX.sym("X", n, N)
        U = ca.SX.sym("U", m, N)
        sg = ca.SX.sym("sg", 1)
        has_avoid = self.safe_nnf is not None
        sa = ca.SX.sym("sa", N if has_avoid else 0)
        fin_lo = np.isfinite(self.low)
        fin_hi = np.isfinite(self.high)
        span = np.where(fin_lo & fin_hi, self.high - self.low, 1.0)
        sb = ca.SX.sym("sb", N)
        g, lbg, ubg = [], [], []
        prev = x0
        for k in range(N):
            xk = X[:, k]
            g.append(xk - self.step_ca(prev, U[:, k]))
            lbg += [0.0] * n
            ubg += [0.0] * n
            prev = xk
            # state space, normalised by its width, with one slack per step
            for i in range(n):
                if fin_lo[i]:
                    g.append((xk[i] - self.low[i]) / span[i] - MARGIN + sb[k])
                    lbg.append(0.0)
                    ubg.append(ca.inf)
                if fin_hi[i]:
                    g.append((self.high[i] - xk[i]) / span[i] - MARGIN + sb[k])
                    lbg.append(0.0)
                    ubg.append(ca.inf)
            if has_avoid:
                for e in self._safe_exprs(xk):
                    g.append(e + sa[k])
                    lbg += [0.0] * e.shape[0]
                    ubg += [ca.inf] * e.shape[0]
        for atom, pos, back in self.goal_dnf_at(N)[j]:
            k = N - back  # the literal's step: x0 (a parameter) at step 0, else a variable
            xk = x0 if k == 0 else X[:, k - 1]
            for e in self._literal_exprs(atom, pos, xk):
                g.append(e + sg)
                lbg += [0.0] * e.shape[0]
                ubg += [ca.inf] * e.shape[0]
        w = ca.vertcat(ca.vec(X), ca.vec(U), sg, sa, sb)
        obj = sg + ca.sum1(sa) + ca.sum1(sb) if has_avoid else sg + ca.sum1(sb)
        nlp = {"x": w, "p": x0, "f": obj, "g": ca.vertcat(*g)}
        solver = ca.nlpsol(f"oracle_N{N}_{j}", "ipopt", nlp, self.opts)
        # variable bounds: X within a generous hull of the state space (keeps finite-escape
        # systems finite), U within the action box, slacks >= 0
        big = np.where(np.isfinite(span), span, 1e6)
        xl = np.where(fin_lo, self.low - big, -np.inf)
        xh = np.where(fin_hi, self.high + big, np.inf)
        nw = w.shape[0]
        lbx = np.concatenate([np.tile(xl, N), np.tile(self.ulow, N), np.zeros(nw - n * N - m * N)])
        ubx = np.concatenate([np.tile(xh, N), np.tile(self.uhigh, N), np.full(nw - n * N - m * N, np.inf)])
        entry = {"solver": solver, "lbx": lbx, "ubx": ubx, "lbg": np.asarray(lbg, float),
                 "ubg": np.asarray([float(v) for v in ubg]), "nw": nw}
        self._solvers[key] = entry
        return entry

    #: Order in which the extra initial guesses are tried (see :meth:`_alternatives`).
    START_ORDER = ("shift", "rollout", "line")

    def _pack(self, N: int, j: int, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        n, m = self.n, self.m
        w = np.zeros(self._solver(N, j)["nw"])
        U = np.clip(U, self.ulow, self.uhigh)
        X = np.where(np.isfinite(X), X, 0.0)
        w[: n * N] = X.ravel()
        w[n * N: n * N + m * N] = U.ravel()
        w[n * N + m * N:] = 1e-2
        return w

    def _shifted(self, N: int, j: int, lower: Optional[dict]) -> Optional[np.ndarray]:
        """This state's solution at N-1, its last state and a zero action appended."""
        if lower is None or N <= 1:
            return None
        n, m = self.n, self.m
        Xp = lower["x"][: n * (N - 1)].reshape(N - 1, n)
        Up = lower["x"][n * (N - 1): n * (N - 1) + m * (N - 1)].reshape(N - 1, m)
        return self._pack(N, j, np.vstack([Xp, Xp[-1:]]), np.vstack([Up, np.zeros((1, m))]))

    def _guess(self, N: int, j: int, x0: np.ndarray, own: dict) -> np.ndarray:
        """The first initial guess: the previous (nearest) state's solution at N, else this
        state's solution at N-1 shifted, else x0 held with zero actions."""
        prev = self._warm.get((N, j))
        if prev is not None:
            return prev["x"]
        w = self._shifted(N, j, own.get(N - 1))
        if w is not None:
            return w
        return self._pack(N, j, np.tile(x0, (N, 1)), np.zeros((N, self.m)))

    def _goal_point(self, N: int, j: int, x0: np.ndarray) -> np.ndarray:
        """x0 with the coordinates the goal constrains directly at step N (state names) set to
        the centre of its regions."""
        target = np.array(x0, float)
        for atom, pos, back in self.goal_dnf_at(N)[j]:
            if not pos or back != 0 or atom.region is None:
                continue
            R = self.regions[atom.region]
            for i, c in enumerate(R.coords):
                k = self.system.symbols.states.get(c)
                if k is None:
                    continue
                if R.kind == "ball":
                    target[k] = R.centre[i]
                else:
                    lo, hi = R.low[i], R.high[i]
                    target[k] = (0.5 * (lo + hi) if math.isfinite(lo) and math.isfinite(hi)
                                 else float(np.clip(target[k], lo, hi)))
        return target

    def _alternatives(self, N: int, j: int, x0: np.ndarray, own: dict):
        """Other initial guesses, in :attr:`START_ORDER`, each different from the first guess:

        * ``shift``: this state's solution at N-1 shifted (when the first guess was a
          neighbour's solution);
        * ``line``: shooting states on the straight line from x0 to the goal's centre, actions at
          the centre of the action box;
        * ``rollout``: a rollout of the constant action at the centre of the action box, then
          of its corners' sign patterns +/-(first action) for bang-bang behaviour.
        """
        n, m = self.n, self.m
        lo = np.where(np.isfinite(self.ulow), self.ulow, -1.0)
        hi = np.where(np.isfinite(self.uhigh), self.uhigh, 1.0)
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        for kind in self.START_ORDER:
            if kind == "shift":
                if (N, j) in self._warm:
                    w = self._shifted(N, j, own.get(N - 1))
                    if w is not None:
                        yield "shift", w
            elif kind == "line":
                target = self._goal_point(N, j, x0)
                s = (np.arange(1, N + 1) / N)[:, None]
                yield "line", self._pack(N, j, x0 + s * (target - x0), np.tile(mid, (N, 1)))
            elif kind == "rollout":
                for sign in (0.0, 1.0, -1.0):
                    u = mid.copy()
                    if m:
                        u[0] = mid[0] + sign * half[0]
                    X = np.empty((N, n))
                    x = np.asarray(x0, float)[None, :]
                    with np.errstate(all="ignore"):
                        for k in range(N):
                            x = self.step_np(x, u[None, :])
                            X[k] = x[0]
                    X = np.clip(X, self.low, self.high)  # keeps a diverging rollout usable
                    name = "rollout" + ("" if sign == 0 else "+" if sign > 0 else "-")
                    yield name, self._pack(N, j, X, np.tile(u, (N, 1)))

    def _solve_nlp(self, N: int, j: int, x0: np.ndarray, w0: np.ndarray):
        """One IPOPT solve: ``(w, objective, clean)``, ``w`` None when it produced nothing usable."""
        entry = self._solver(N, j)
        try:
            sol = entry["solver"](x0=w0, p=x0, lbx=entry["lbx"], ubx=entry["ubx"],
                                  lbg=entry["lbg"], ubg=entry["ubg"])
            status = entry["solver"].stats().get("return_status", "unknown")
            w = np.asarray(sol["x"]).ravel()
            obj = float(sol["f"])
        except Exception:  # noqa: BLE001 - IPOPT/CasADi errors are solver failures, never crashes
            return None, math.inf, False
        if not np.all(np.isfinite(w)) or not math.isfinite(obj):
            return None, math.inf, False
        # a failed solve can still carry a feasible point: the replay judges it
        return w, obj, status in GOOD_STATUSES

    def first_passing_prefix(self, x0: np.ndarray, actions: np.ndarray) -> Optional[int]:
        """The smallest k >= 1 such that the first k actions fulfil the task (replayed), or None."""
        tr, _ = self.replay(x0, actions)
        for k in range(1, tr.shape[0]):
            if not np.all(np.isfinite(tr[k])):
                return None
            if self.trajectory_ok(tr[: k + 1]):
                return k
        return None

    def _try(self, N: int, x0: np.ndarray, own: dict):
        """Solve every disjunct at N, with up to :attr:`restarts` extra initial guesses each
        while the optimum is positive. Returns ``(status, actions, failures, solves, restarts)``,
        status ok / no / failed. "ok" also when the replay of some solution's first k <= N
        actions already fulfils the task (then ``actions`` has k rows)."""
        n, m = self.n, self.m
        failures = solves = extra = 0
        for j in range(len(self.goal_dnf_at(N))):
            best_w, best_obj = None, math.inf
            alts = itertools.islice(self._alternatives(N, j, x0, own), self.restarts)
            for name, w0 in itertools.chain([("first", self._guess(N, j, x0, own))], alts):
                w, obj, clean = self._solve_nlp(N, j, x0, w0)
                solves += 1
                extra += name != "first"
                failures += not clean
                if w is None:
                    continue
                if obj < best_obj:
                    best_w, best_obj = w, obj
                U = w[n * N: n * N + m * N].reshape(N, m)
                p = self.first_passing_prefix(x0, U)
                if obj <= FEASIBLE_TOL or p is not None:
                    # feasible (the replay in solve() judges it), or a prefix of the replay
                    # already fulfils the task although the slack is positive
                    own[N] = self._warm[(N, j)] = {"x": w}
                    return "ok", (U if p is None else U[:p]), failures, solves, extra
            if best_w is not None:
                own[N] = self._warm[(N, j)] = {"x": best_w}
        return ("failed" if failures else "no"), None, failures, solves, extra

    # ------------------------------------------------------------------ replay
    def replay(self, x0: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, bool]:
        """Roll ``actions`` out with the simulator's step; ``(trajectory [N+1, n], passes)``."""
        x = np.asarray(x0, float)[None, :]
        traj = [x[0]]
        for u in np.asarray(actions, float).reshape(-1, self.m):
            x = self.step_np(x, np.clip(u, self.ulow, self.uhigh)[None, :])
            traj.append(np.asarray(x[0], float))
        tr = np.asarray(traj)
        return tr, self.trajectory_ok(tr)

    def trajectory_ok(self, tr: np.ndarray) -> bool:
        if not np.all(np.isfinite(tr)):
            return False
        N = tr.shape[0] - 1
        later = tr[1:]
        if np.any(later < self.low) or np.any(later > self.high):
            return False
        t = self.task.model
        if not bool(offline.satisfied(t.asap, tr[None])[0, N]):
            return False
        if t.avoid is not None and N > 0 and bool(np.any(offline.satisfied(t.avoid, tr[None])[0, 1:])):
            return False
        return True

    # ------------------------------------------------------------------ public
    def solve(self, x0: Sequence[float], index: int = 0) -> StateResult:
        """The minimum number of steps from ``x0`` (see the module docstring)."""
        start = time.perf_counter()
        x0 = np.asarray(x0, float).ravel()
        if x0.shape != (self.n,) or not np.all(np.isfinite(x0)):
            return StateResult(index, x0, None, "nan", False, seconds=time.perf_counter() - start)
        tr0 = x0[None, :]
        if self.trajectory_ok(tr0):
            return StateResult(index, x0, 0, "solved", True, actions=np.zeros((0, self.m)),
                               trajectory=tr0, seconds=time.perf_counter() - start)
        lb = max(1, self.lower_bound(x0, until=start + self.time_limit))
        failures = solves = restarts = 0
        own: dict[int, dict] = {}
        for N in range(lb, self.deadline + 1):
            if time.perf_counter() - start > self.time_limit:
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

    def solve_many(self, states: np.ndarray, indices: Optional[Sequence[int]] = None,
                   progress: Optional[Callable[[int], None]] = None) -> list[StateResult]:
        """Solve ``states`` in nearest-neighbour order (warm starts), results in input order;
        ``progress(1)`` after each state."""
        states = np.asarray(states, float).reshape(-1, self.n)
        idx = list(range(len(states))) if indices is None else list(indices)
        order = nearest_neighbour_order(states, self.system)
        out: list[Optional[StateResult]] = [None] * len(states)
        for k in order:
            out[k] = self.solve(states[k], idx[k])
            if progress is not None:
                progress(1)

        return out  # type: ignore[return-value]


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


# --------------------------------------------------------------------------- consistency
def tighten(prog, reports: Sequence["OracleReport"]) -> dict[str, int]:
    """Make the local minima of tasks sharing an ``asap`` consistent; returns, per task, how
    many states improved.

    Where one task's constraints (``avoid``, deadline) are a superset of another's — ``reach_avoid``
    against ``reach`` — each of its action sequences is also admissible for the other, so a
    state's ``reach`` minimum cannot exceed its ``reach_avoid`` minimum; a local search can still
    miss it. For every pair of reports of ``prog`` with the same ``asap`` (states matched by
    their x0), each action sequence found for one task is replayed under the other task's own
    check (:meth:`Oracle.first_passing_prefix`, the simulator's step) and adopted when its
    shortest passing prefix is shorter than that state's minimum (or the state had none, or an
    unverified one). Sequences of the less constrained task are tried too: they count when their
    replay happens to satisfy the stricter task. Every adopted sequence is verified by replay; the
    result records the task it came from in ``source``. Reports are changed in place and each
    gets ``extra["tightened"]``.
    """
    oracles = {rep.task: Oracle(prog, rep.task, restarts=0) for rep in reports}  # no NLP is built
    originals = {id(rep): list(rep.results) for rep in reports}
    summary: dict[str, int] = {}
    for rep in reports:
        o = oracles[rep.task]
        asap = ir.to_text(o.task.model.asap)
        by_x0 = {np.asarray(r.x0, float).tobytes(): i for i, r in enumerate(rep.results)}
        improved: set[int] = set()
        sources: list[str] = []
        for other in reports:
            if other is rep or other.task == rep.task or other.system != rep.system:
                continue
            if ir.to_text(oracles[other.task].task.model.asap) != asap:
                continue
            sources.append(other.task)
            for r in originals[id(other)]:
                if r.steps is None or r.actions is None or r.steps == 0:
                    continue
                i = by_x0.get(np.asarray(r.x0, float).tobytes())
                if i is None:
                    continue
                cur = rep.results[i]
                if cur.steps is not None and cur.verified and cur.steps <= r.steps:
                    continue
                acts = np.asarray(r.actions, float)[: o.deadline]
                k = o.first_passing_prefix(cur.x0, acts)
                if k is None or (cur.steps is not None and cur.verified and k >= cur.steps):
                    continue
                tr, ok = o.replay(cur.x0, acts[:k])
                if not ok:  # first_passing_prefix checked the same replay: never here
                    continue
                rep.results[i] = replace(cur, steps=k, status="solved", verified=True, actions=acts[:k],
                                         trajectory=tr, source=other.task)
                improved.add(i)
        rep.extra["tightened"] = {"from": sources, "improved_states": len(improved)}
        summary[rep.task] = len(improved)
    return summary


# --------------------------------------------------------------------------- drivers
_WORKER_ORACLES: dict = {}  # in a worker process: one Oracle (and its built solvers) per setting


def _worker(payload):
    """Process entry: re-load the spec from its text (programs hold compiled closures), once per
    process and setting: the chunks a worker solves share its solvers and warm starts."""
    import asap_dsl

    source, name, task, states, indices, ipopt, restarts, interval_bound, time_limit = payload
    key = (source, name, task, repr(ipopt), restarts, interval_bound, time_limit)
    oracle = _WORKER_ORACLES.get(key)
    if oracle is None:
        _WORKER_ORACLES.clear()
        oracle = _WORKER_ORACLES[key] = Oracle(asap_dsl.loads(source, name), task, ipopt, restarts, interval_bound,
                                               time_limit)
    return [r.to_dict(with_actions=True) for r in oracle.solve_many(states, indices)]


def run(prog, task: Optional[str] = None, episodes: int = 1000, seed: int = EVAL_SEED, workers: int = 1,
        states: Optional[np.ndarray] = None, ipopt_options: Optional[dict] = None,
        restarts: Optional[int] = None, interval_bound: bool = True,
        time_limit: float = STATE_TIME_LIMIT, progress: Optional[Callable[[int], None]] = None) -> OracleReport:
    """The oracle over ``episodes`` evaluation states (or the given ``states``).

    ``restarts`` / ``interval_bound``: see :class:`Oracle` (defaults: :data:`RESTARTS` extra
    initial guesses on non-linear systems, and the interval lower bound there).

    ``workers > 1`` splits the nearest-neighbour tour into contiguous chunks solved in separate
    processes (each builds its own solvers; about eight chunks per worker, so that the work
    stays balanced and progress is seen). ``time_limit``: seconds of search per state, then
    ``timeout``. ``progress(k)`` is called as k more states are done.
    """
    start = time.perf_counter()
    oracle = Oracle(prog, task, ipopt_options, restarts, interval_bound, time_limit)  # validates system and task up front
    t = oracle.task.model
    if states is None:
        states = task_states(prog.system, t, episodes, seed=seed)
        used_seed: Optional[int] = seed
    else:
        used_seed = None
    states = np.asarray(states, float).reshape(-1, oracle.n)
    workers = max(1, min(int(workers), len(states)))
    if workers == 1:
        results = oracle.solve_many(states, progress=progress)
    else:
        import multiprocessing as mp

        order = nearest_neighbour_order(states, prog.system)
        chunks = np.array_split(np.asarray(order), min(len(states), 8 * workers))
        payloads = [(prog.source, prog.file, oracle.task_name, states[c], [int(i) for i in c], ipopt_options,
                     restarts, interval_bound, time_limit) for c in chunks if len(c)]
        method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
        parts = []
        with mp.get_context(method).Pool(workers) as pool:
            for part in pool.imap_unordered(_worker, payloads):
                parts.append(part)
                if progress is not None:
                    progress(len(part))
        by_index = {d["index"]: StateResult.from_dict(d) for part in parts for d in part}
        results = [by_index[i] for i in range(len(states))]
        for r in results:  # trajectories are not shipped back: replay here (cheap)
            if r.actions is not None:
                r.trajectory, _ = oracle.replay(r.x0, r.actions)
    return OracleReport(prog.file, oracle.task_name, prog.system.name, oracle.label, oracle.deadline,
                        oracle.tolerances, used_seed, results, time.perf_counter() - start, workers)


def minimum_steps(prog, x0: Sequence[float], task: Optional[str] = None) -> StateResult:
    """The oracle's answer for one initial state."""
    return Oracle(prog, task).solve(x0)


#: ``lint --deep`` searches at most about this many seconds per task (split over its samples).
DEEP_TASK_SECONDS = 60.0


def deadline_infeasible(prog, task_name: Optional[str] = None, samples: int = 32, seed: int = 0,
                        workers: int = 2, seconds: float = DEEP_TASK_SECONDS) -> list[tuple[np.ndarray, str, str]]:
    """Sampled initial states that were not shown to reach ``asap`` within the deadline (for
    ``lint --deep``): ``(state, status, reason)``, the status ``infeasible``, ``solver_failed``,
    ``nan`` or ``timeout`` (the search of that state used up its share of ``seconds``, the
    time for the task), the reason a few words. Empty when every sample reaches the goal
    in time. Raises :class:`OracleUnsupported` for a black-box system or a non-region task."""
    workers = max(1, min(workers, samples))
    per_state = max(0.5, seconds * workers / max(1, samples))
    oracle = Oracle(prog, task_name, time_limit=per_state)
    states = task_states(prog.system, oracle.task.model, samples, seed=seed)
    report = run(prog, oracle.task_name, states=states, workers=workers, time_limit=per_state)
    how = {
        "infeasible": "proved by a convex problem" if oracle.label == "exact" else "a local search (IPOPT) found no way",
        "solver_failed": "the solver failed",
        "nan": "the dynamics give non-finite values",
    }
    out = []
    for r in report.results:
        if r.status == "timeout":
            out.append((r.x0, r.status, f"no way found in {per_state:.3g} s of search, which reached "
                        f"{r.horizon:,} of the {oracle.deadline:,} steps"))
        elif r.status in how:
            out.append((r.x0, r.status, how[r.status]))
    return out


__all__ = ["DEEP_TASK_SECONDS", "MARGIN", "STATE_TIME_LIMIT", "Oracle", "OracleReport", "OracleUnsupported", "StateResult", "deadline_infeasible",
           "minimum_steps", "nearest_neighbour_order", "run", "tighten"]
