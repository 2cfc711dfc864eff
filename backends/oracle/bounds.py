"""The oracle's analysis of the dynamics and its lower bounds on the horizon: which systems are
linear, and the smallest N that a sound test does not exclude (a support-function test for
linear dynamics, interval reachability for non-linear ones). :class:`HorizonBounds` is one part of
:class:`asap_dsl.backends.oracle.search.Oracle`, which holds one."""

from __future__ import annotations

import math
import time
from typing import Callable, Optional, Sequence

import numpy as np

from asap_dsl import ast
from asap_dsl.diagnostics import Span
from asap_dsl.dynamics import affine_probe
from asap_dsl.expr import INTERVAL, compile_function, degree
from asap_dsl.intervals import Interval

__all__ = ["INTERVAL_SLACK", "HorizonBounds", "coords_linear", "is_linear"]

#: Relative widening of the interval enclosure per step (covers floating-point rounding).
INTERVAL_SLACK = 1e-9


def is_linear(system) -> bool:
    """Whether the one-step map of ``system`` (an ``ode`` or ``map``) is affine in state and action:
    an exact (zero-order hold) integrator, or equations of degree at most 1."""
    if system.kind == "ode" and system.integrator.method == "exact":
        return True
    return all(degree(e, system.symbols) <= 1 for e in system.equations)


def coords_linear(system, region) -> bool:
    """Whether every coordinate of ``region`` (a region of the program) is linear in the state."""
    return all(degree(ast.Name(c, Span()), system.symbols) <= 1 for c in region.coords)


class HorizonBounds:
    """Lower bounds on the horizon of one task: the smallest N that a sound test does not exclude.

    :param system: the system (``ode`` or ``map``).
    :param regions: the program's regions by name.
    :param regions_now: per alternative of ``asap`` (at the deadline), the regions it must be
        inside at step N itself (:attr:`asap_dsl.backends.oracle.goals.Goals.regions_now`).
    :param deadline: the task's deadline; a bound of ``deadline + 1`` means out of reach.
    :param step: the simulator's one-step map (:func:`asap_dsl.dynamics.numpy_step`).
    :param interval_bound: use interval reachability for non-linear dynamics (else the bound is 0).
    """

    def __init__(self, system, regions: dict, regions_now: Sequence[tuple[str, ...]], deadline: int,
                 step: Callable[[np.ndarray, np.ndarray], np.ndarray], interval_bound: bool = True):
        self.system = system
        self.regions = regions
        self.regions_now = list(regions_now)
        self.deadline = int(deadline)
        self.interval_bound = bool(interval_bound)
        self.n, self.m = system.n_state, system.n_action
        self.linear = is_linear(system)
        #: ``(A, B, c)`` of the (linear) one-step map, probed through the simulator's step.
        with np.errstate(all="ignore"):
            self.affine = affine_probe(step, self.n, self.m) if self.linear else None
        if self.affine is not None and not all(np.all(np.isfinite(a)) for a in self.affine):
            self.affine = None  # a step beyond a float's range (dt = 1e308): the test would exclude on NaN
            self.linear = False
        self._interval_fns: Optional[tuple] = None

    def _coord_affine(self, region: str):
        """``(P, p)`` with region values ``v = P x + p`` (linear coordinates only)."""
        values = self.regions[region].values
        P, _, p = affine_probe(lambda x, u: values(x), self.n, 0)
        return P, p

    def lower_bound(self, x0: np.ndarray, until: float = math.inf) -> int:
        """The smallest N not excluded by a sound test: the support-function test for linear
        dynamics, interval reachability for non-linear ones (0 when disabled). At the clock time
        ``until`` (``time.perf_counter``) the test stops where it is: still a lower bound."""
        if not self.regions_now:
            return 0
        if not self.linear:
            return self.interval_lower_bound(x0, until) if self.interval_bound else 0
        A, B, c = self.affine
        affine = {r: self._coord_affine(r) for conj in self.regions_now for r in conj}
        free = np.asarray(x0, float)
        gens: list[np.ndarray] = []  # B, A B, A^2 B, ... (A^j B multiplies u_{N-1-j})
        Aj_B = B.copy()
        for N in range(self.deadline + 1):
            if N % 256 == 255 and time.perf_counter() > until:
                return N
            if N > 0:
                with np.errstate(all="ignore"):
                    free = A @ free + c
                    gens.append(Aj_B)
                    Aj_B = A @ Aj_B
                if not (np.all(np.isfinite(free)) and np.all(np.isfinite(Aj_B))):
                    return N  # past a float's range the test excludes nothing: N is still a lower bound
            for conj in self.regions_now:
                if all(self._inside_possible(r, affine[r], free, gens) for r in conj):
                    return N
        return self.deadline + 1

    def _inside_possible(self, region: str, aff, free, gens) -> bool:
        """False only if the reachable set of step N is separated from ``region`` (support function
        along the direction from the free response to the region)."""
        P, p = aff
        R = self.regions[region]
        y = P @ free + p
        if R.kind == "ball":
            diff = np.asarray(R.centre) - y
            gap = float(np.linalg.norm(diff)) - R.radius
        else:
            proj = np.clip(y, R.low, R.high)
            diff = proj - y
            gap = float(np.linalg.norm(diff))
        if gap <= 0:
            return True
        if not gens:
            return False
        e = diff / np.linalg.norm(diff)
        d = P.T @ e
        g = np.stack([G.T @ d for G in gens])  # [N, m]
        s = self.system
        reach = float(np.sum(np.maximum(g * s.action_low, g * s.action_high)))
        return gap <= reach + 1e-9 * (1 + abs(gap))

    # ------------------------------------------------------------------ interval bound
    def _interval_setup(self):
        if self._interval_fns is None:
            s = self.system
            rhs = compile_function(s.equations, s.symbols, INTERVAL)
            coords = {r: compile_function([ast.Name(c, Span()) for c in self.regions[r].coords], s.symbols, INTERVAL)
                      for conj in self.regions_now for r in conj}
            self._interval_fns = (rhs, coords)
        return self._interval_fns

    def _interval_step(self, S: list, A: list) -> list:
        """An enclosure of the one-step map over the box ``S`` of states and ``A`` of actions
        (the simulator's own integrator, evaluated in interval arithmetic)."""
        rhs = self._interval_setup()[0]
        s = self.system
        f = lambda xs: list(rhs(xs, A))  # noqa: E731
        if s.kind == "map":
            return f(S)
        dh = s.dt / s.integrator.substeps
        for _ in range(s.integrator.substeps):
            if s.integrator.method == "euler":
                S = [x + dh * k for x, k in zip(S, f(S))]
            else:
                k1 = f(S)
                k2 = f([x + (0.5 * dh) * k for x, k in zip(S, k1)])
                k3 = f([x + (0.5 * dh) * k for x, k in zip(S, k2)])
                k4 = f([x + dh * k for x, k in zip(S, k3)])
                S = [x + (dh / 6.0) * (a + 2.0 * b + 2.0 * c + d) for x, a, b, c, d in zip(S, k1, k2, k3, k4)]
        return [Interval.of(x) for x in S]

    def _goal_possible(self, S: list) -> bool:
        """False only if no point of the box ``S`` satisfies any disjunct of ``asap``."""
        coords = self._interval_setup()[1]
        for conj in self.regions_now:
            ok = True
            for region in conj:
                R = self.regions[region]
                v = [Interval.of(c) for c in coords[region](S, ())]
                if R.kind == "ball":
                    d2 = 0.0
                    for iv, c in zip(v, R.centre):
                        gap = max(iv.lo - c, c - iv.hi, 0.0)
                        d2 += gap * gap
                    if not d2 <= R.radius ** 2 * (1 + 1e-9) + 1e-12:
                        ok = False
                else:
                    for iv, lo, hi in zip(v, R.low, R.high):
                        tol = 1e-9 * (1 + abs(lo) + abs(hi))
                        if not (iv.lo <= hi + tol and iv.hi >= lo - tol):
                            ok = False
                if not ok:
                    break
            if ok:
                return True
        return False

    def interval_lower_bound(self, x0: np.ndarray, until: float = math.inf) -> int:
        """The first N at which the interval enclosure of the reachable set (all action
        sequences, states kept inside the state space at steps 1..N, as the task requires) can
        meet ``asap``; ``deadline + 1`` when it cannot up to the deadline. Sound: the enclosure
        contains every admissible trajectory's state, widened each step for rounding."""
        s = self.system
        A = [Interval(float(lo), float(hi)) for lo, hi in zip(s.action_low, s.action_high)]
        S = [Interval(float(v), float(v)) for v in x0]
        try:
            for N in range(1, self.deadline + 1):
                if N % 256 == 0 and time.perf_counter() > until:
                    return N
                S = self._interval_step(S, A)
                out = []
                for iv, lo, hi in zip(S, s.state_low, s.state_high):
                    if math.isnan(iv.lo) or math.isnan(iv.hi):
                        return N  # lost the enclosure: no bound from here on
                    w = INTERVAL_SLACK * (1.0 + max(abs(iv.lo), abs(iv.hi)))
                    a, b = max(iv.lo - w, float(lo)), min(iv.hi + w, float(hi))
                    if a > b:
                        return self.deadline + 1  # no admissible trajectory stays in the state space
                    out.append(Interval(a, b))
                S = out
                if self._goal_possible(S):
                    return N
        except (ZeroDivisionError, OverflowError, ValueError, TypeError):
            return N
        return self.deadline + 1
