"""The oracle's optimisation problems: one elastic multiple-shooting NLP per (horizon N,
alternative of ``asap``), built once with CasADi and solved by IPOPT for every initial state (x0
is the NLP's parameter), with the initial guesses that start it.

The NLP's variables are the states at steps 1..N, the actions at steps 0..N-1 and non-negative
slacks: one for the goal, one per step for ``avoid`` and one per step for the state space. The
objective is the sum of slacks, so the NLP is always feasible and N is feasible exactly when the
optimum is zero. Balls are squared distances (``|v-c|^2 <= (r-d)^2`` inside, ``>= (r+d)^2``
outside), boxes are linear sides; the goal is shrunk and ``avoid`` and the state space are grown
by :data:`MARGIN` so that the solution survives the replay. The search over N is
:class:`asap_dsl.backends.oracle.search.Oracle`.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Iterator, Optional

import numpy as np

from asap_dsl import ast
from asap_dsl.diagnostics import Span
from asap_dsl.expr import casadi_namespace, compile_function
from asap_dsl.stl import ir

from .clock import Work
from .goals import AllOf, Constant, Goals, Literal, Normal, flatten_and

__all__ = ["GOOD_STATUSES", "IPOPT_OPTIONS", "MARGIN", "START_ORDER", "ShootingProblems"]

#: Margin by which the goal is shrunk and ``avoid`` / the state space are kept clear in the NLP.
MARGIN = 1e-6
#: Solver return statuses that count as a clean solve.
GOOD_STATUSES = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
#: IPOPT's callbacks, whose evaluations the simulated clock counts.
CALLBACKS = ("nlp_f", "nlp_g", "nlp_grad_f", "nlp_jac_g", "nlp_hess_l")
#: Order in which the extra initial guesses are tried (see :meth:`ShootingProblems.other_guesses`).
START_ORDER = ("shift", "rollout", "line")

IPOPT_OPTIONS = {
    "ipopt.print_level": 0,
    "ipopt.sb": "yes",
    "print_time": False,
    "ipopt.tol": 1e-9,
    "ipopt.constr_viol_tol": 1e-9,
    "ipopt.acceptable_tol": 1e-7,
    "ipopt.max_iter": 400,
    "ipopt.mu_strategy": "adaptive",
    # A guess whose dynamics overflow is the solve's status (Invalid_Number_Detected: the search
    # tries the next guess), not a CasADi warning on the user's terminal mid-progress.
    "show_eval_warnings": False,
}


class ShootingProblems:
    """The NLPs of one task, built on first use and kept, with the last solution of each (the
    warm start of the next, nearest, initial state).

    :param system: the system (``ode`` or ``map``).
    :param regions: the program's regions by name.
    :param goals: the task's normal forms.
    :param step_ca: the one-step map on CasADi symbols (:func:`asap_dsl.dynamics.casadi_step`).
    :param step_np: the simulator's one-step map (:func:`asap_dsl.dynamics.numpy_step`), for the
        rollout guesses.
    :param options: the ``nlpsol`` options (IPOPT's prefixed ``ipopt.``).
    """

    def __init__(self, system, regions: dict, goals: Goals, step_ca: Callable, step_np: Callable, options: dict):
        import casadi as ca

        self.ca = ca
        self.system, self.regions, self.goals = system, regions, goals
        self.step_ca, self.step_np, self.options = step_ca, step_np, options
        self.n, self.m = system.n_state, system.n_action
        self.low, self.high = system.state_low, system.state_high
        self.ulow, self.uhigh = system.action_low, system.action_high
        self._coords_fn: dict[Any, Any] = {}  # region name, or id of a comparison margin -> compiled
        self._built: dict[tuple[int, int], dict] = {}
        self._warm: dict[tuple[int, int], np.ndarray] = {}   # last solution per (N, alternative)
        self.work = Work()  # what every solve computed: the simulated clock's (:mod:`.clock`)

    # ------------------------------------------------------------------ conditions
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

    def _formula_expr(self, f: Normal, x):
        """One scalar expression >= 0 when the normal form holds (fmin/fmax)."""
        ca = self.ca
        if isinstance(f, Constant):
            return ca.DM(1.0 if f.value else -1.0)
        if isinstance(f, Literal):
            parts = self._literal_exprs(f.atom, f.positive, x)  # (an `avoid` literal: no step back)
            flat = [p[i] for p in parts for i in range(p.shape[0])]
            out = flat[0]
            for p in flat[1:]:
                out = ca.fmin(out, p)
            return out
        subs = [self._formula_expr(g, x) for g in f.parts]
        out = subs[0]
        for s in subs[1:]:
            out = ca.fmin(out, s) if isinstance(f, AllOf) else ca.fmax(out, s)
        return out

    def _safe_exprs(self, x) -> list:
        """``avoid`` kept false at the state ``x``: expressions each >= 0 (one per literal when it is
        a conjunction of literals, which IPOPT handles better than one fmin)."""
        f = self.goals.safe
        if isinstance(f, Literal):
            return self._literal_exprs(f.atom, f.positive, x)
        conjuncts = flatten_and(f)
        if isinstance(f, AllOf) and all(isinstance(g, Literal) for g in conjuncts):
            return [e for g in conjuncts for e in self._literal_exprs(g.atom, g.positive, x)]
        return [self._formula_expr(f, x)]

    # ------------------------------------------------------------------ the NLP
    def _problem(self, N: int, j: int) -> dict:
        key = (N, j)
        if key in self._built:
            return self._built[key]
        ca = self.ca
        n, m = self.n, self.m
        x0 = ca.SX.sym("x0", n)
        X = ca.SX.sym("X", n, N)
        U = ca.SX.sym("U", m, N)
        sg = ca.SX.sym("sg", 1)
        has_avoid = self.goals.safe is not None
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
        for lit in self.goals.at(N)[j]:
            k = N - lit.back  # the literal's step: x0 (a parameter) at step 0, else a variable
            xk = x0 if k == 0 else X[:, k - 1]
            for e in self._literal_exprs(lit.atom, lit.positive, xk):
                g.append(e + sg)
                lbg += [0.0] * e.shape[0]
                ubg += [ca.inf] * e.shape[0]
        w = ca.vertcat(ca.vec(X), ca.vec(U), sg, sa, sb)
        obj = sg + ca.sum1(sa) + ca.sum1(sb) if has_avoid else sg + ca.sum1(sb)
        nlp = {"x": w, "p": x0, "f": obj, "g": ca.vertcat(*g)}
        solver = ca.nlpsol(f"oracle_N{N}_{j}", "ipopt", nlp, self.options)
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
        self._built[key] = entry
        return entry

    def _count(self, entry: dict, stats: dict) -> None:
        """Add one solve's work (its callbacks' instructions, its iterations over the variables)."""
        if "instructions" not in entry:
            entry["instructions"] = {name: _instructions(entry["solver"], name) for name in CALLBACKS}
        self.work.instructions += sum(int(stats.get("n_call_" + name, 0)) * k
                                      for name, k in entry["instructions"].items())
        self.work.variable_iterations += (int(stats.get("iter_count", 0)) + 1) * entry["nw"]
        self.work.solves += 1

    def solve(self, N: int, j: int, x0: np.ndarray, w0: np.ndarray) -> tuple[Optional[np.ndarray], float, bool]:
        """One IPOPT solve of alternative ``j`` at horizon ``N`` from ``x0``, started at ``w0``:
        ``(w, objective, clean)``, ``w`` None when it produced nothing usable, ``clean`` whether
        IPOPT's return status is one of :data:`GOOD_STATUSES`. Never raises."""
        entry = self._problem(N, j)
        try:
            sol = entry["solver"](x0=w0, p=x0, lbx=entry["lbx"], ubx=entry["ubx"],
                                  lbg=entry["lbg"], ubg=entry["ubg"])
            stats = entry["solver"].stats()
            status = stats.get("return_status", "unknown")
            self._count(entry, stats)
            w = np.asarray(sol["x"]).ravel()
            obj = float(sol["f"])
        except Exception:  # noqa: BLE001 - IPOPT/CasADi errors are solver failures, never crashes
            return None, math.inf, False
        if not np.all(np.isfinite(w)) or not math.isfinite(obj):
            return None, math.inf, False
        # a failed solve can still carry a feasible point: the replay judges it
        return w, obj, status in GOOD_STATUSES

    def actions(self, N: int, w: np.ndarray) -> np.ndarray:
        """The actions ``[N, m]`` of a solution ``w`` at horizon ``N``."""
        n, m = self.n, self.m
        return w[n * N: n * N + m * N].reshape(N, m)

    def remember(self, N: int, j: int, w: np.ndarray) -> None:
        """Keep ``w`` as the warm start of alternative ``j`` at ``N`` for the next initial state."""
        self._warm[(N, j)] = w

    def forget(self) -> None:
        """Drop the warm starts: the next state starts cold, as in a fresh process."""
        self._warm.clear()

    # ------------------------------------------------------------------ initial guesses
    def _pack(self, N: int, j: int, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        n, m = self.n, self.m
        w = np.zeros(self._problem(N, j)["nw"])
        U = np.clip(U, self.ulow, self.uhigh)
        X = np.where(np.isfinite(X), X, 0.0)
        w[: n * N] = X.ravel()
        w[n * N: n * N + m * N] = U.ravel()
        w[n * N + m * N:] = 1e-2
        return w

    def _shifted(self, N: int, j: int, lower: Optional[np.ndarray]) -> Optional[np.ndarray]:
        """This state's solution at N-1, its last state and a zero action appended."""
        if lower is None or N <= 1:
            return None
        n, m = self.n, self.m
        Xp = lower[: n * (N - 1)].reshape(N - 1, n)
        Up = lower[n * (N - 1): n * (N - 1) + m * (N - 1)].reshape(N - 1, m)
        return self._pack(N, j, np.vstack([Xp, Xp[-1:]]), np.vstack([Up, np.zeros((1, m))]))

    def first_guess(self, N: int, j: int, x0: np.ndarray, own: dict[int, np.ndarray]) -> np.ndarray:
        """The first initial guess: the previous (nearest) state's solution at N, else this
        state's solution at N-1 (``own[N - 1]``) shifted, else x0 held with zero actions."""
        prev = self._warm.get((N, j))
        if prev is not None:
            return prev
        w = self._shifted(N, j, own.get(N - 1))
        if w is not None:
            return w
        return self._pack(N, j, np.tile(x0, (N, 1)), np.zeros((N, self.m)))

    def _goal_point(self, N: int, j: int, x0: np.ndarray) -> np.ndarray:
        """x0 with the coordinates the goal constrains directly at step N (state names) set to
        the centre of its regions."""
        target = np.array(x0, float)
        for lit in self.goals.at(N)[j]:
            if not lit.positive or lit.back != 0 or lit.atom.region is None:
                continue
            R = self.regions[lit.atom.region]
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

    def other_guesses(self, N: int, j: int, x0: np.ndarray, own: dict[int, np.ndarray]) -> Iterator[tuple[str, np.ndarray]]:
        """Other initial guesses ``(name, w)``, in :data:`START_ORDER`, each different from the
        first guess:

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
        for kind in START_ORDER:
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


def _instructions(solver, name: str) -> int:
    """The CasADi instructions of one of the solver's callbacks (0 where CasADi does not say)."""
    try:
        return int(solver.get_function(name).n_instructions())
    except Exception:  # noqa: BLE001 - a clock's estimate, never a failed solve
        return 0
