"""The online monitor for one trace (batch 1): Python floats, no numpy per step.

A single environment updates its monitors once per step, one state at a time. There the batched
:class:`asap_dsl.stl.online.Monitor` pays numpy's fixed cost per call on arrays of one element;
this monitor computes the same values with Python floats: the atoms through their scalar forms
(:class:`asap_dsl.expr.ScalarForm`), each operator as a small closure over its own state, past
windows with monotone deques (amortised O(1) per step whatever the window's length).

The values are those of the offline evaluator at every step (the tests check it), with the same
encoding of satisfaction as the batched monitor: a second lane where an atom is +1 when it holds
and -1 when not, ``true``/``false`` and empty windows ±inf, on which not/and/or/min/max windows are
the Boolean operators. ``since`` is rewritten as in the batched monitor.

Same interface as ``Monitor`` with ``batch = 1``: ``update(states [1, n], mask=None) -> [1]``,
``.robustness``, ``.satisfied``, ``.t``, ``reset(mask=None)``, ``update_and_restart``.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Callable, Optional

import numpy as np

from ..expr import ScalarForm
from . import ir
from .online import MonitorValues

_INF = math.inf
_F64 = np.dtype(np.float64)


class ScalarMonitor(MonitorValues, ir.NodeCompiler):
    """Online monitor of a causal formula over one trace (see the module docstring)."""

    batch = 1

    def __init__(self, node: ir.Formula, *, satisfaction: bool = True, n_state: Optional[int] = None):
        if not ir.is_causal(node):
            raise ValueError("ScalarMonitor needs a causal formula (past operators only)")
        self.node, self.n_state, self._track_sat = node, n_state, bool(satisfaction)
        self._R: list[float] = []   # each node's robustness at the newest step
        self._S: list[float] = []   # each node's satisfaction lane (+1 / -1 / ±inf)
        self._row: list = [None]    # the newest state, as a tuple of floats
        self._steps: list[Callable[[int], None]] = []
        self._resets: list[Callable[[], None]] = []
        self._memo: dict[int, tuple[object, int]] = {}
        self._root = self._compile(node)
        self._run = _chain(self._steps)
        self._t = -1
        self._shape = (1, n_state) if n_state is not None else None  # of the states the fast path takes
        self._rob = np.full(1, np.nan)
        self._sat = np.zeros(1, dtype=bool)

    # ---- public ------------------------------------------------------------------------------
    @property
    def t(self) -> np.ndarray:
        return np.array([self._t])


    def reset(self, mask=None) -> None:
        if mask is not None and not _flag(mask, "reset"):
            return
        self._t = -1
        for r in self._resets:
            r()

    def update(self, states, mask=None) -> np.ndarray:
        """Append ``states [1, n]`` (unless ``mask`` is ``[False]``); ρ at the newest step, ``[1]``."""
        row = None
        if mask is None and type(states) is np.ndarray and states.dtype is _F64 and states.shape == self._shape:
            row = states.tolist()[0]  # the common case, checked cheaply: finite unless the sum is not
            total = sum(row)
            if total - total != 0.0:
                row = None
        if row is None:
            if mask is not None and not _flag(mask, "update"):
                return self._rob
            row = self._read(states)
            self._shape = (1, len(row))
        self._row[0] = row
        t = self._t = self._t + 1
        self._run(t)
        rob = np.empty(1)
        rob[0] = self._R[self._root]
        self._rob = rob
        if self._track_sat:
            self._sat = np.array([self._S[self._root] > 0.0])
        return rob

    def update_and_restart(self, states, done, cand):
        """``update(states)``, then, if ``done``, ``reset()`` and ``update(cand)``; returns ρ (and ⊨)
        of the reached state."""
        rho = self.update(states)
        sat = self._sat if self._track_sat else None
        if _flag(done, "restart"):
            self.reset()
            self.update(cand)
        return rho, sat

    # ---- input -------------------------------------------------------------------------------
    def _read(self, states) -> tuple:
        s = np.asarray(states, dtype=np.float64)
        if s.shape[0] != 1 or s.ndim != 2:
            raise ValueError(f"states must have shape [1, n_state]; got {s.shape}")
        if self.n_state is not None and s.shape[1] != self.n_state:
            raise ValueError(f"states have {s.shape[1]} state component(s); expected {self.n_state}")
        row = tuple(s[0].tolist())
        if not math.isfinite(math.fsum(row)) and not all(map(math.isfinite, row)):
            i = next(k for k, v in enumerate(row) if not math.isfinite(v))
            raise ValueError(f"states contain a non-finite value ({row[i]}) at batch index 0, state component {i}")
        return row

    # ---- compilation -------------------------------------------------------------------------
    def _slot(self) -> int:
        self._R.append(math.nan)
        self._S.append(math.nan)
        return len(self._R) - 1

    def _compile_node(self, node) -> int:
        R, S, sat = self._R, self._S, self._track_sat
        if isinstance(node, ir.Atom):
            i = self._slot()
            self._steps.append(_atom_step(node, i, R, S, self._row, sat))
            return i
        if isinstance(node, ir.Const):
            i = self._slot()
            R[i] = S[i] = _INF if node.value else -_INF
            return i
        if isinstance(node, ir.Not):
            a = self._compile(node.arg)
            i = self._slot()

            def neg(t, a=a, i=i):
                R[i] = -R[a]
                if sat:
                    S[i] = -S[a]
            self._steps.append(neg)
            return i
        if isinstance(node, (ir.And, ir.Or, ir.Implies)):
            a, b = self._compile(node.left), self._compile(node.right)
            i = self._slot()
            self._steps.append(_binary_step(type(node), a, b, i, R, S, sat))
            return i
        if isinstance(node, (ir.Historically, ir.Once)):
            a = self._compile(node.arg)
            i = self._slot()
            step, reset = _window_step(isinstance(node, ir.Historically), node.interval, a, i, R, S, sat)
            self._steps.append(step)
            self._resets.append(reset)
            return i
        if isinstance(node, ir.Since):
            core = ir.since_unbounded_form(node)
            if core is not node:
                return self._compile(core)
            a, b = self._compile(node.left), self._compile(node.right)
            i = self._slot()
            step, reset = _since_step(a, b, i, R, S, sat)
            self._steps.append(step)
            self._resets.append(reset)
            return i
        raise TypeError(f"not a causal formula node: {node!r}")


def _chain(steps: list) -> Callable[[int], None]:
    """One function calling every step in order (no loop per update)."""
    names = [f"_s{k}" for k in range(len(steps))]
    source = "def run(t):\n" + "".join(f"    {n}(t)\n" for n in names) + "    return None\n"
    namespace = dict(zip(names, steps))
    exec(compile(source, "<scalar monitor>", "exec"), namespace)  # noqa: S102 - our own generated code
    return namespace["run"]


def _flag(mask, what: str) -> bool:
    m = np.asarray(mask)
    if m.shape != (1,) or m.dtype != np.bool_:
        raise ValueError(f"{what} mask must be a bool array of shape (1,); got {m.dtype} {m.shape}")
    return bool(m[0])


def _atom_step(atom: ir.Atom, i: int, R: list, S: list, row: list, sat: bool):
    form = atom.scalar
    if form is None:  # an atom without a scalar form: its vectorised functions on a batch of one
        def form(r, _atom=atom):
            s = np.asarray(r, dtype=np.float64)[None]
            return float(_atom.robustness(s)[0]), bool(_atom.satisfied(s)[0])

    def step(t, form=form):
        r, b = form(row[0])
        R[i] = r
        S[i] = 1.0 if b else -1.0

    if not sat and isinstance(form, ScalarForm):  # robustness only: the compiled margin called directly
        fast = form.compiled_rho()

        def step_rho(t, fast=fast, form=form):
            try:
                r = fast(row[0])
            except (ArithmeticError, ValueError):
                r = form(row[0])[0]
            if r != r:  # NaN: as numpy computes it
                r = form(row[0])[0]
            R[i] = r
        return step_rho
    return step


def _binary_step(kind: type, a: int, b: int, i: int, R: list, S: list, sat: bool):
    # min/max as numpy computes them on these values (no NaN reaches here: atoms fall back).
    if not sat and kind is not ir.Implies:  # robustness only: one lane, no test per step
        if kind is ir.And:
            def lone(t):
                x, y = R[a], R[b]
                R[i] = x if x <= y else y
        else:
            def lone(t):
                x, y = R[a], R[b]
                R[i] = x if x >= y else y
        return lone
    if kind is ir.And:
        def step(t):
            x, y = R[a], R[b]
            R[i] = x if x <= y else y
            if sat:
                x, y = S[a], S[b]
                S[i] = x if x <= y else y
    elif kind is ir.Or:
        def step(t):
            x, y = R[a], R[b]
            R[i] = x if x >= y else y
            if sat:
                x, y = S[a], S[b]
                S[i] = x if x >= y else y
    else:  # a -> b is max(-a, b)
        def step(t):
            x, y = -R[a], R[b]
            R[i] = x if x >= y else y
            if sat:
                x, y = -S[a], S[b]
                S[i] = x if x >= y else y
    return step


def _window_step(every: bool, interval: ir.Interval, a: int, i: int, R: list, S: list, sat: bool):
    """historically (``every``) or once over ``[lo, hi]`` steps back: the child's values of steps
    ``t - hi .. t - lo`` (cut at 0), by a monotone deque; empty windows are ±inf."""
    lo, hi = interval.lo, interval.hi
    empty = _INF if every else -_INF
    lanes = [(R, deque(), deque(), deque())] + ([(S, deque(), deque(), deque())] if sat else [])
    running = [empty, empty]  # unbounded windows: the running extremum per lane

    def reset():
        for _, delay, idx, val in lanes:
            delay.clear()
            idx.clear()
            val.clear()
        running[0] = running[1] = empty

    if not sat and lo == 0 and hi is not None:  # the common case, one lane: no loop over lanes
        _, _, idx, val = lanes[0]
        return _ONE_LANE_WINDOW[every](R, a, i, hi, val, idx), reset

    def step(t):
        for lane, (X, delay, idx, val) in enumerate(lanes):
            v = X[a]
            if lo:
                delay.append(v)
                if len(delay) <= lo:  # no value old enough yet: the window is empty
                    (R if lane == 0 else S)[i] = empty
                    continue
                v = delay.popleft()
            out = R if lane == 0 else S
            if hi is None:
                acc = running[lane]
                acc = (v if v < acc else acc) if every else (v if v > acc else acc)
                running[lane] = out[i] = acc
                continue
            k = t - lo  # the step whose value v is
            if every:
                while val and val[-1] >= v:
                    val.pop()
                    idx.pop()
            else:
                while val and val[-1] <= v:
                    val.pop()
                    idx.pop()
            val.append(v)
            idx.append(k)
            first = t - hi
            while idx[0] < first:
                idx.popleft()
                val.popleft()
            out[i] = val[0]
    return step, reset


# The one-lane window step, min (historically) and max (once), generated from one text: the
# comparison written into each rather than passed in (a call per element costs a third more).
_ONE_LANE_SOURCE = """
def make(R, a, i, hi, val, idx):
    push, popv, popi, appi = val.append, val.pop, idx.pop, idx.append
    left_v, left_i = val.popleft, idx.popleft

    def step(t):
        v = R[a]
        while val and val[-1] {evict} v:
            popv()
            popi()
        push(v)
        appi(t)
        first = t - hi
        while idx[0] < first:
            left_i()
            left_v()
        R[i] = val[0]
    return step
"""


def _one_lane_factory(evict: str) -> Callable:
    namespace: dict = {}
    exec(compile(_ONE_LANE_SOURCE.format(evict=evict), "<scalar window>", "exec"), namespace)  # noqa: S102
    return namespace["make"]


#: ``every`` (historically: evict larger values) -> factory; else once (evict smaller ones).
_ONE_LANE_WINDOW = {True: _one_lane_factory(">="), False: _one_lane_factory("<=")}


def _since_step(a: int, b: int, i: int, R: list, S: list, sat: bool):
    """φ S ψ over the whole past: ``S(t) = max(ψ(t), min(φ(t), S(t-1)))``, ``S(-1) = -inf``."""
    prev = [-_INF, -_INF]

    def reset():
        prev[0] = prev[1] = -_INF

    def step(t):
        phi, psi, p = R[a], R[b], prev[0]
        m = phi if phi <= p else p
        prev[0] = R[i] = psi if psi >= m else m
        if sat:
            phi, psi, p = S[a], S[b], prev[1]
            m = phi if phi <= p else p
            prev[1] = S[i] = psi if psi >= m else m
    return step, reset


__all__ = ["ScalarMonitor"]
