"""Online, batched STL monitors over the formula IR, equal to the offline evaluator at every step.

Public API
----------
``Monitor(node, batch, *, satisfaction=True, n_state=None)``
    For **causal** formulas (atoms, boolean operators, ``historically``/``once``/``since`` with
    bounded or unbounded intervals). ``update(states [B, n]) -> [B]`` appends one state to every
    trace of the batch and returns ρ(s̄, t, φ) at the newest step t (float64), exactly
    ``offline.robustness(φ, trace so far)[..., t]``. After an update, ``.robustness`` holds the same
    array and ``.satisfied`` the Boolean semantics (s̄, t) ⊨ φ at that step (computed exactly on
    booleans, not by the sign; pass ``satisfaction=False`` to skip that work, then ``.satisfied``
    raises). ``.t`` is the per-entry step index of the newest state (``-1`` before the first update
    of an entry). ``reset(mask=None)`` starts a new trace for every entry (or those where the bool
    ``[B]`` mask is True): their next ``update`` is step 0. Resets cost O(1) per entry: every entry
    has its own start step; nothing is cleared.
``PrefixMonitor(node, batch, *, satisfaction=True, n_state=None)``
    For boolean combinations of ``eventually[a, b] ψ``, ``always[a, b] ψ`` and ``ψ1 until[a, b] ψ2``
    with causal ψ's, and of causal parts (taken at t = 0). ``update`` returns the robustness **at
    time 0 of the prefix** s_0..s_t (windows cut at the end of the prefix), i.e. exactly
    ``offline.robustness(φ, prefix)[..., 0]``: running max/min, frozen once the window has closed.
    Same ``.robustness``, ``.satisfied``, ``.t``, ``reset`` as ``Monitor``. This is what the ``rho``
    reward of ``eventually[0, D] asap and always[0, D] not avoid`` needs every step.
``monitor_for(node, batch, **kw)``
    ``Monitor`` for a causal formula, ``PrefixMonitor`` where that applies, else ``ValueError``.

Cost: O(1) amortised per node per step, vectorised over the batch (no per-entry Python objects).
A bounded past window ``[lo, hi]`` keeps ring buffers of the child's values aligned to a global
step counter and uses online van Herk/Gil-Werman: blocks of the window length ``w = hi - lo + 1``;
a running prefix aggregate (restarted at block starts and at each entry's own step 0), and the
block's suffix aggregates computed once when the block completes (one vectorised ``accumulate``
every ``w`` steps). A window ``[max(g-hi, start_b), g-lo]`` then spans at most two blocks and is
``op(suffix[start_b], prefix[g-lo])``. Unbounded past windows are running min/max of the value
delayed by ``lo``. ``since`` is rewritten exactly (see :mod:`asap_dsl.stl.offline`)::

    φ S[a,b] ψ  =  H[0,a-1] φ  and  O[a,a]( O[0,b-a] ψ  and  φ S ψ )

with the unbounded strict since ``S(t) = max(ψ(t), min(φ(t), S(t-1)))``.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from . import ir

__all__ = ["Monitor", "PrefixMonitor", "monitor_for"]


# --------------------------------------------------------------------------------------------
# The shared clock: a global step counter g and each entry's own start step.
# --------------------------------------------------------------------------------------------


class _Clock:
    def __init__(self, batch: int):
        self.batch = batch
        self.g = -1  # global index of the newest update
        self.start = np.zeros(batch, dtype=np.int64)  # global step of each entry's t = 0
        self.t = np.full(batch, -1, dtype=np.int64)
        self.rows = np.arange(batch)


# --------------------------------------------------------------------------------------------
# Online operators. Each computes its value at the newest step from its children's values.
# --------------------------------------------------------------------------------------------


class _Op:
    kids: tuple = ()


class _AtomOp(_Op):
    def __init__(self, atom: ir.Atom, boolean: bool, batch: int):
        self.atom, self.boolean, self.batch = atom, boolean, batch
        self.fn = atom.satisfied if boolean else atom.robustness
        self.dtype = np.bool_ if boolean else np.float64

    def step(self, clock, states, vals):
        v = np.asarray(self.fn(states))
        if v.shape != (self.batch,):
            try:
                v = np.broadcast_to(v, (self.batch,))
            except ValueError:
                raise ValueError(
                    f"atom {self.atom.text!r} returned shape {v.shape}; expected ({self.batch},)"
                ) from None
        return v.astype(self.dtype, copy=False)


class _ConstOp(_Op):
    def __init__(self, value, dtype, batch):
        self.v = np.full(batch, value, dtype=dtype)

    def step(self, clock, states, vals):
        return self.v


class _FuncOp(_Op):
    def __init__(self, fn, kids):
        self.fn, self.kids = fn, kids

    def step(self, clock, states, vals):
        return self.fn(*(vals[k] for k in self.kids))


class _PastUnbounded(_Op):
    """op over the child's values at steps [0, t - lo] of each entry (running min/max)."""

    def __init__(self, kid, lo, op, ident, dtype, batch):
        self.kids, self.lo, self.op, self.ident = (kid,), lo, op, ident
        self.acc = np.full(batch, ident, dtype=dtype)
        self.empty = np.full(batch, ident, dtype=dtype)
        self.ring = np.empty((lo + 1, batch), dtype=dtype) if lo else None

    def step(self, clock, states, vals):
        x = vals[self.kids[0]]
        g, lo = clock.g, self.lo
        if lo:
            self.ring[g % (lo + 1)] = x
            if g < lo:
                return self.empty
            x = self.ring[(g - lo) % (lo + 1)]
        d = g - lo
        first = clock.start == d
        acc = self.op(self.acc, x)
        if first.any():
            acc = np.where(first, x, acc)
        self.acc = acc
        valid = clock.start <= d
        return acc if valid.all() else np.where(valid, acc, self.ident)


class _PastBounded(_Op):
    """op over the child's values at steps [t - hi, t - lo] of each entry (online van Herk)."""

    def __init__(self, kid, lo, hi, op, ident, dtype, batch):
        self.kids, self.lo, self.hi, self.op, self.ident = (kid,), lo, hi, op, ident
        self.w = w = hi - lo + 1
        self.C = C = w * (-(-(hi + 1) // w))  # ring capacity: >= hi + 1 and a multiple of w
        self.xb = np.empty((w, batch), dtype=dtype)  # the current block's raw values
        self.pre = np.empty((C, batch), dtype=dtype)  # prefix aggregates (restarted at step 0)
        self.suf = np.empty((C, batch), dtype=dtype)  # suffix aggregates of completed blocks
        self.empty = np.full(batch, ident, dtype=dtype)

    def step(self, clock, states, vals):
        x = vals[self.kids[0]]
        g, w, C, op = clock.g, self.w, self.C, self.op
        r = g % w
        self.xb[r] = x
        if r == 0:
            pre = x
        else:
            pre = op(self.pre[(g - 1) % C], x)
            restart = clock.start == g
            if restart.any():
                pre = np.where(restart, x, pre)
        self.pre[g % C] = pre
        if r == w - 1:  # block complete: its suffix aggregates, once per w steps
            base = (g - w + 1) % C
            self.suf[base : base + w] = op.accumulate(self.xb[::-1], axis=0)[::-1]
        end = g - self.lo
        if end < 0:
            return self.empty
        start = np.maximum(clock.start, g - self.hi)
        pre_end = self.pre[end % C]
        if w == 1:
            res = pre_end
        else:
            split = (start // w) != (end // w)
            if split.any():
                res = np.where(split, op(self.suf[start % C, clock.rows], pre_end), pre_end)
            else:
                res = pre_end
        valid = start <= end
        return res if valid.all() else np.where(valid, res, self.ident)


class _SinceUnbounded(_Op):
    """Strict unbounded since: S(t) = join(ψ(t), meet(φ(t), S(t-1))), S(-1) = bottom."""

    def __init__(self, left, right, bottom, dtype, batch):
        self.kids = (left, right)
        self.bottom = bottom
        self.S = np.full(batch, bottom, dtype=dtype)

    def step(self, clock, states, vals):
        phi, psi = vals[self.kids[0]], vals[self.kids[1]]
        S = np.maximum(psi, np.minimum(phi, self.S))
        first = clock.t == 0
        if first.any():
            S = np.where(first, psi, S)
        self.S = S
        return S


def _future_name(node) -> Optional[str]:
    """The first future operator in ``node`` (pre-order), as text, or None."""
    if isinstance(node, ir.FUTURE_OPERATORS):
        return f"{type(node).__name__.lower()}{node.interval}"
    for c in ir.children(node):
        name = _future_name(c)
        if name:
            return name
    return None


class _Graph:
    """A compiled, topologically ordered list of online operators for several causal roots."""

    def __init__(self, roots, boolean: bool, batch: int):
        self.boolean, self.batch = boolean, batch
        self.dtype = np.bool_ if boolean else np.float64
        self.bottom, self.top = (False, True) if boolean else (-np.inf, np.inf)
        self.ops: list[_Op] = []
        self.memo: dict[int, tuple[object, int]] = {}
        self.keep: list = []  # rewritten nodes kept alive (ids stay unique)
        self.outputs = [self._compile(r) for r in roots]

    def _add(self, op) -> int:
        self.ops.append(op)
        return len(self.ops) - 1

    def _compile(self, node) -> int:
        hit = self.memo.get(id(node))
        if hit is not None:
            return hit[1]
        idx = self._compile_node(node)
        self.memo[id(node)] = (node, idx)
        return idx

    def _compile_node(self, node) -> int:
        B, dt, boolean = self.batch, self.dtype, self.boolean
        if isinstance(node, ir.Atom):
            return self._add(_AtomOp(node, boolean, B))
        if isinstance(node, ir.Const):
            return self._add(_ConstOp(self.top if node.value else self.bottom, dt, B))
        neg = np.logical_not if boolean else np.negative
        if isinstance(node, ir.Not):
            return self._add(_FuncOp(neg, (self._compile(node.arg),)))
        if isinstance(node, (ir.And, ir.Or, ir.Implies)):
            kids = (self._compile(node.left), self._compile(node.right))
            if isinstance(node, ir.And):
                fn = np.minimum
            elif isinstance(node, ir.Or):
                fn = np.maximum
            else:
                fn = lambda a, b: np.maximum(neg(a), b)  # noqa: E731
            return self._add(_FuncOp(fn, kids))
        if isinstance(node, (ir.Historically, ir.Once)):
            kid = self._compile(node.arg)
            if isinstance(node, ir.Historically):
                op, ident = np.minimum, self.top
            else:
                op, ident = np.maximum, self.bottom
            lo, hi = node.interval.lo, node.interval.hi
            if hi is None:
                return self._add(_PastUnbounded(kid, lo, op, ident, dt, B))
            return self._add(_PastBounded(kid, lo, hi, op, ident, dt, B))
        if isinstance(node, ir.Since):
            lo, hi = node.interval.lo, node.interval.hi
            if lo == 0 and hi is None:
                kids = (self._compile(node.left), self._compile(node.right))
                return self._add(_SinceUnbounded(*kids, self.bottom, dt, B))
            core = ir.Since(ir.Interval(0, None), node.left, node.right)
            if hi is not None:
                core = ir.And(ir.Once(ir.Interval(0, hi - lo), node.right), core)
            if lo > 0:
                core = ir.And(
                    ir.Historically(ir.Interval(0, lo - 1), node.left),
                    ir.Once(ir.Interval(lo, lo), core),
                )
            self.keep.append(core)
            return self._compile(core)
        if isinstance(node, ir.FUTURE_OPERATORS):
            raise ValueError(
                f"the online monitor needs a causal formula, but {_future_name(node)} looks into "
                f"the future; use the past form (historically/once/since), or offline.robustness"
            )
        raise TypeError(f"not a formula node: {node!r}")

    def step(self, clock, states) -> list:
        vals = [None] * len(self.ops)
        for i, op in enumerate(self.ops):
            vals[i] = op.step(clock, states, vals)
        return [vals[i] for i in self.outputs]


# --------------------------------------------------------------------------------------------
# Public monitors
# --------------------------------------------------------------------------------------------


class _Base:
    def __init__(self, batch: int, satisfaction: bool, n_state: Optional[int]):
        if not isinstance(batch, (int, np.integer)) or batch < 1:
            raise ValueError(f"batch must be a positive integer; got {batch!r}")
        self.batch = int(batch)
        self.n_state = n_state
        self._track_sat = bool(satisfaction)
        self._clock = _Clock(self.batch)
        self._rob = np.full(self.batch, np.nan)
        self._sat = np.zeros(self.batch, dtype=bool)

    @property
    def t(self) -> np.ndarray:
        """Per-entry step index of the newest state (-1 before an entry's first update)."""
        return self._clock.t.copy()

    @property
    def robustness(self) -> np.ndarray:
        """The value returned by the last ``update``."""
        return self._rob

    @property
    def satisfied(self) -> np.ndarray:
        """The Boolean semantics at the newest step (exact, not the sign of the robustness)."""
        if not self._track_sat:
            raise ValueError("this monitor was built with satisfaction=False")
        return self._sat

    def reset(self, mask=None) -> None:
        """Start new traces: all entries, or those where ``mask`` (bool ``[B]``) is True."""
        c = self._clock
        if mask is None:
            c.start[:] = c.g + 1
            c.t[:] = -1
            return
        m = np.asarray(mask)
        if m.shape != (self.batch,) or m.dtype != np.bool_:
            raise ValueError(f"reset mask must be a bool array of shape ({self.batch},); got {m.dtype} {m.shape}")
        c.start[m] = c.g + 1
        c.t[m] = -1

    def _check_states(self, states) -> np.ndarray:
        s = np.asarray(states, dtype=np.float64)
        if s.ndim != 2 or s.shape[0] != self.batch:
            raise ValueError(f"states must have shape [{self.batch}, n_state]; got {s.shape}")
        if self.n_state is not None and s.shape[1] != self.n_state:
            raise ValueError(f"states have {s.shape[1]} state component(s); expected {self.n_state}")
        if not np.isfinite(s).all():
            b, i = (int(v) for v in np.argwhere(~np.isfinite(s))[0])
            raise ValueError(
                f"states contain a non-finite value ({s[b, i]}) at batch index {b}, state component {i}"
            )
        return s

    def _tick(self) -> _Clock:
        c = self._clock
        c.g += 1
        np.subtract(c.g, c.start, out=c.t)
        return c


class Monitor(_Base):
    """Online monitor of a causal formula: ρ (and ⊨) at the newest step of each trace."""

    def __init__(self, node: ir.Formula, batch: int, *, satisfaction: bool = True,
                 n_state: Optional[int] = None):
        super().__init__(batch, satisfaction, n_state)
        name = _future_name(node)
        if name is not None:
            raise ValueError(
                f"Monitor needs a causal formula, but {name} looks into the future; use the past "
                f"form (historically/once/since), PrefixMonitor for top-level bounded future "
                f"operators, or offline.robustness"
            )
        self.node = node
        self._g_rob = _Graph([node], False, self.batch)
        self._g_sat = _Graph([node], True, self.batch) if self._track_sat else None

    def update(self, states) -> np.ndarray:
        """Append ``states [B, n]`` to every trace; return ρ at the newest step, float64 ``[B]``."""
        s = self._check_states(states)
        c = self._tick()
        (r,) = self._g_rob.step(c, s)
        self._rob = np.array(r, dtype=np.float64)
        if self._g_sat is not None:
            (b,) = self._g_sat.step(c, s)
            self._sat = np.array(b, dtype=bool)
        return self._rob


# ---- prefix monitor -------------------------------------------------------------------------


def _prefix_plan(node, leaves: list):
    """Split ``node`` into a boolean skeleton over leaves; raise ValueError if not a prefix formula."""
    if ir.is_causal(node):
        leaves.append(("causal", node))
        return ("leaf", len(leaves) - 1)
    if isinstance(node, ir.Not):
        return ("not", _prefix_plan(node.arg, leaves))
    if isinstance(node, (ir.And, ir.Or, ir.Implies)):
        kind = {ir.And: "and", ir.Or: "or", ir.Implies: "implies"}[type(node)]
        return (kind, _prefix_plan(node.left, leaves), _prefix_plan(node.right, leaves))
    if isinstance(node, (ir.Eventually, ir.Always)):
        if not ir.is_causal(node.arg):
            raise ValueError(
                f"PrefixMonitor supports future operators only at the top of the formula; "
                f"{_future_name(node.arg)} is nested inside {type(node).__name__.lower()}{node.interval}"
            )
        leaves.append((type(node).__name__.lower(), node))
        return ("leaf", len(leaves) - 1)
    if isinstance(node, ir.Until):
        for side in (node.left, node.right):
            if not ir.is_causal(side):
                raise ValueError(
                    f"PrefixMonitor supports future operators only at the top of the formula; "
                    f"{_future_name(side)} is nested inside until{node.interval}"
                )
        leaves.append(("until", node))
        return ("leaf", len(leaves) - 1)
    # A past operator over a future one.
    raise ValueError(
        f"no online monitor for this formula: {_future_name(node)} sits under the past operator "
        f"{type(node).__name__.lower()}; only causal formulas (Monitor) or top-level future "
        f"operators over causal arguments (PrefixMonitor) can be monitored online"
    )


class _PrefixLeaf:
    """Value at time 0 of one top-level leaf over the prefix, in O(1) per step."""

    def __init__(self, kind, node, graph_idx, lat_bottom, lat_top, dtype, batch):
        self.kind = kind
        self.idx = graph_idx  # indices into the causal graph's outputs
        self.bottom, self.top = lat_bottom, lat_top
        if kind in ("eventually", "until"):
            init = lat_bottom
        elif kind == "always":
            init = lat_top
        else:
            init = lat_bottom  # causal: overwritten at t = 0
        self.acc = np.full(batch, init, dtype=dtype)
        self.init = init
        self.hmin = np.full(batch, lat_top, dtype=dtype)  # until: min of φ over [0, t)
        if kind != "causal":
            self.lo, self.hi = node.interval.lo, node.interval.hi

    def step(self, t, outs):
        kind = self.kind
        first = t == 0
        if kind == "causal":
            v = outs[self.idx[0]]
            self.acc = np.where(first, v, self.acc)
            return self.acc
        acc = np.where(first, self.init, self.acc)
        inwin = t >= self.lo
        if self.hi is not None:
            inwin &= t <= self.hi
        if kind == "until":
            phi, psi = outs[self.idx[0]], outs[self.idx[1]]
            hmin = np.where(first, self.top, self.hmin)
            cand = np.maximum(acc, np.minimum(psi, hmin))
            self.hmin = np.minimum(hmin, phi)
        else:
            v = outs[self.idx[0]]
            cand = np.maximum(acc, v) if kind == "eventually" else np.minimum(acc, v)
        self.acc = np.where(inwin, cand, acc)
        return self.acc


class PrefixMonitor(_Base):
    """ρ at time 0 of the prefix seen so far, for top-level future operators over causal parts."""

    def __init__(self, node: ir.Formula, batch: int, *, satisfaction: bool = True,
                 n_state: Optional[int] = None):
        super().__init__(batch, satisfaction, n_state)
        self.node = node
        leaves: list = []
        self._plan = _prefix_plan(node, leaves)
        roots, idx = [], []
        for kind, leaf in leaves:
            if kind == "causal":
                parts = (leaf,)
            elif kind == "until":
                parts = (leaf.left, leaf.right)
            else:
                parts = (leaf.arg,)
            idx.append(tuple(range(len(roots), len(roots) + len(parts))))
            roots.extend(parts)
        self._lanes = []
        for boolean in ((False, True) if self._track_sat else (False,)):
            graph = _Graph(roots, boolean, self.batch)
            lv = [_PrefixLeaf(kind, leaf, ix, graph.bottom, graph.top, graph.dtype, self.batch)
                  for (kind, leaf), ix in zip(leaves, idx)]
            self._lanes.append((graph, lv, boolean))

    def _combine(self, plan, vals, boolean):
        kind = plan[0]
        if kind == "leaf":
            return vals[plan[1]]
        neg = np.logical_not if boolean else np.negative
        if kind == "not":
            return neg(self._combine(plan[1], vals, boolean))
        a = self._combine(plan[1], vals, boolean)
        b = self._combine(plan[2], vals, boolean)
        if kind == "and":
            return np.minimum(a, b)
        if kind == "or":
            return np.maximum(a, b)
        return np.maximum(neg(a), b)

    def update(self, states) -> np.ndarray:
        """Append ``states [B, n]``; return ρ at time 0 of each prefix s_0..s_t, float64 ``[B]``."""
        s = self._check_states(states)
        c = self._tick()
        for graph, leaves, boolean in self._lanes:
            outs = graph.step(c, s)
            vals = [leaf.step(c.t, outs) for leaf in leaves]
            res = self._combine(self._plan, vals, boolean)
            if boolean:
                self._sat = np.array(res, dtype=bool)
            else:
                self._rob = np.array(res, dtype=np.float64)
        return self._rob


def monitor_for(node: ir.Formula, batch: int, **kw):
    """``Monitor`` for a causal formula, ``PrefixMonitor`` for top-level future operators over
    causal parts; otherwise ``ValueError`` naming the operator that cannot be monitored online."""
    if ir.is_causal(node):
        return Monitor(node, batch, **kw)
    return PrefixMonitor(node, batch, **kw)
