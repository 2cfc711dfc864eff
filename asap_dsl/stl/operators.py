"""The compiled operator graph behind the online monitors (:mod:`asap_dsl.stl.online`): per-column
clocks, one step method per formula node, each writing into its own preallocated buffer.

Layout. Robustness and satisfaction run in **one pass** over ``L * B`` columns (``L = 2`` lanes
with satisfaction, else 1): lane 0 holds ρ, lane 1 the Boolean value encoded as ``+1``/``-1``
(``±inf`` for ``true``/``false`` and for empty windows). On that encoding ``not``/``and``/``or``/
``->``/min/max windows are negation/min/max exactly as on booleans, so both lanes share every
numpy call, and ``satisfied = lane1 > 0`` is exact (lane 1 is never 0; it comes from the atoms'
``satisfied``, never from ρ). The formula is compiled into a flat, topologically ordered list of
bound step methods, each writing into its own preallocated output buffer (``out=`` arguments).

Clock. Every column has its own step counter ``n`` (the position of its newest value in its ring
buffers) and its start ``start`` (``t = n - start``). While all counters are equal (no masked
update, or masked updates of freshly reset entries only: these are relabelled to the common
counter) the monitor is *aligned* and runs the fast path: one scalar counter ``g``, scalar ring
indices, steady-state windows with scalar block arithmetic, and the minimum ``t`` kept in O(1) so
restart checks are skipped when no entry is young. Otherwise (arbitrary masks) the general path
computes every operator for all columns as if they advanced, with per-column ring indices, and
commits the new counters and the running accumulators (unbounded windows, since, prefix leaves)
for the masked columns only. Ring slots written for an unmasked column are the slots of its next
step, overwritten when it really advances and never read before, so the speculative writes are
harmless; a full ``reset()`` realigns everything.

Windows. A bounded past window ``[lo, hi]`` keeps ring buffers of the child's values and uses
online van Herk/Gil-Werman: blocks of the window length ``w = hi - lo + 1``; a running prefix
aggregate (restarted at block starts and at each entry's own step 0), and the block's suffix
aggregates computed once when the block completes (one vectorised ``accumulate`` every ``w``
steps of a column). A window ``[max(n-hi, start), n-lo]`` then spans at most two blocks and is
``op(suffix[max(n-hi, start)], prefix[n-lo])``. Unbounded past windows are running min/max of the
value delayed by ``lo``. ``since`` is rewritten exactly (see :mod:`asap_dsl.stl.offline`)::

    φ S[a,b] ψ  =  H[0,a-1] φ  and  O[a,a]( O[0,b-a] ψ  and  φ S ψ )

with the unbounded strict since ``S(t) = max(ψ(t), min(φ(t), S(t-1)))``.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from . import ir

__all__ = ["INF", "Clock", "Graph", "commit", "future_name"]

INF = np.inf


# --------------------------------------------------------------------------------------------
# The clock: per-column step counters and starts; a scalar counter while they are all equal.
# --------------------------------------------------------------------------------------------


class Clock:
    def __init__(self, batch: int, lanes: int):
        self.B, self.L = batch, lanes
        self.N = N = batch * lanes
        self.cols = np.arange(N)
        self.n = np.full(N, -1, dtype=np.int64)  # counter of each column's newest value (general path)
        self.start = np.zeros(N, dtype=np.int64)  # counter value of each column's t = 0
        self.t = np.full(N, -1, dtype=np.int64)  # per-column t of the newest value
        self.aligned = True  # all counters equal to g (then self.n is not maintained)
        self.g = -1
        self.smax = 0  # max(start) while aligned: min t = g - smax
        self.tmin = -1
        self.mask = None  # [N] bool during a masked general-path update
        self.n_new = self.n
        self.states = None
        self._t_keep = self.t

    def tile(self, mask_b: np.ndarray) -> np.ndarray:
        return mask_b if self.L == 1 else np.tile(mask_b, self.L)

    def reset(self, mask_n) -> None:
        if mask_n is None:
            m = self.g if self.aligned else int(self.n.max())
            self.g, self.aligned, self.smax = m, True, m + 1
            self.start.fill(m + 1)
            self.t.fill(-1)
            return
        if self.aligned:
            self.start[mask_n] = self.g + 1
            self.smax = self.g + 1
        else:
            self.start[mask_n] = self.n[mask_n] + 1
        self.t[mask_n] = -1

    def fast_tick(self, states) -> None:
        self.states = states
        self.g = g = self.g + 1
        np.subtract(g, self.start, out=self.t)
        self.tmin = g - self.smax

    def slow_begin(self, states, mask_n) -> None:
        if self.aligned:
            self.n.fill(self.g)
            self.aligned = False
        if mask_n is not None:
            fresh = mask_n & (self.t == -1)
            if fresh.any():  # a fresh trace can take any counter: join the newest ones
                m = int(self.n.max())
                self.n[fresh] = m - 1
                self.start[fresh] = m
        self.states, self.mask = states, mask_n
        self.n_new = self.n + 1
        self._t_keep = self.t
        self.t = self.n_new - self.start
        self.tmin = int(self.t.min())

    def slow_end(self) -> None:
        mask, t_new = self.mask, self.t
        self.t = self._t_keep
        if mask is None:
            self.n[:] = self.n_new
            self.t[:] = t_new
        else:
            np.copyto(self.n, self.n_new, where=mask)
            np.copyto(self.t, t_new, where=mask)
        self.mask = None
        n = self.n
        if (n == n[0]).all():
            self.aligned, self.g, self.smax = True, int(n[0]), int(self.start.max())


def commit(state: np.ndarray, new: np.ndarray, mask) -> None:
    if mask is None:
        state[...] = new
    else:
        np.copyto(state, new, where=mask)


# --------------------------------------------------------------------------------------------
# Online operators. Each writes its value at the newest step into ``self.out`` ([N] float64).
# ``fast(ck)`` runs on an aligned clock without a mask, ``slow(ck)`` anywhere.
# --------------------------------------------------------------------------------------------


class _Op:
    def __init__(self, ck: Clock):
        self.out = np.empty(ck.N)

    def slow(self, ck):
        self.fast(ck)


class _AtomOp(_Op):
    def __init__(self, atom: ir.Atom, ck: Clock):
        super().__init__(ck)
        self.atom = atom
        self.rob, self.rob_fn = self.out[: ck.B], atom.robustness
        self.sat = self.out[ck.B:] if ck.L == 2 else None
        self.sat_fn = atom.satisfied
        self.lanes = self.out.reshape(ck.L, ck.B)  # [L, B] view of out

    def values(self, s: np.ndarray) -> np.ndarray:
        """The atom on the rows of ``s`` ([R, n]), both lanes: [L, R] (lane 1 as +1/-1)."""
        v = np.empty((self.lanes.shape[0], s.shape[0]))
        self._put(v[0], self.rob_fn(s))
        if self.sat is not None:
            b = np.asarray(self.sat_fn(s))
            self._put(v[1], np.where(b, 1.0, -1.0) if b.ndim else (1.0 if b else -1.0))
        return v

    def _put(self, dst, v):
        try:
            np.copyto(dst, v, casting="unsafe")
        except ValueError:
            raise ValueError(
                f"atom {self.atom.text!r} returned shape {np.shape(v)}; expected ({dst.shape[0]},)"
            ) from None

    def fast(self, ck):
        s = ck.states
        self._put(self.rob, self.rob_fn(s))
        if self.sat is not None:
            b = np.asarray(self.sat_fn(s))
            self._put(self.sat, np.where(b, 1.0, -1.0) if b.ndim else (1.0 if b else -1.0))


class _ConstOp(_Op):
    def __init__(self, value: float, ck):
        super().__init__(ck)
        self.out.fill(value)

    def fast(self, ck):
        pass


class _NotOp(_Op):
    def __init__(self, a, ck):
        super().__init__(ck)
        self.a = a.out

    def fast(self, ck):
        np.negative(self.a, out=self.out)


class _BinOp(_Op):
    def __init__(self, fn, a, b, ck):
        super().__init__(ck)
        self.fn, self.a, self.b = fn, a.out, b.out

    def fast(self, ck):
        self.fn(self.a, self.b, out=self.out)


class _ImpliesOp(_BinOp):
    def fast(self, ck):
        out = self.out
        np.negative(self.a, out=out)
        np.maximum(out, self.b, out=out)


class _PastUnbounded(_Op):
    """op over the child's values at steps [0, t - lo] of each entry (running min/max)."""

    def __init__(self, kid, lo, op, ident, ck):
        super().__init__(ck)
        self.x, self.lo, self.op, self.ident = kid.out, lo, op, ident
        self.out.fill(ident)  # the running aggregate itself (ident where t < lo)
        self.ring = np.full((lo + 1, ck.N), ident) if lo else None

    def fast(self, ck):
        x, lo, acc = self.x, self.lo, self.out
        if lo:
            g = ck.g
            self.ring[g % (lo + 1)] = x
            x = self.ring[(g - lo) % (lo + 1)]
        self.op(acc, x, out=acc)
        if ck.tmin <= lo:
            t = ck.t
            np.copyto(acc, x, where=t == lo)
            if ck.tmin < lo:
                acc[t < lo] = self.ident

    def slow(self, ck):
        x, lo, t = self.x, self.lo, ck.t
        if lo:
            n = ck.n_new
            self.ring[n % (lo + 1), ck.cols] = x
            x = self.ring[(n - lo) % (lo + 1), ck.cols]
        new = np.where(t == lo, x, self.op(self.out, x))
        new[t < lo] = self.ident
        commit(self.out, new, ck.mask)


class _PastBounded(_Op):
    """op over the child's values at steps [t - hi, t - lo] of each entry (online van Herk)."""

    def __init__(self, kid, lo, hi, op, ident, ck):
        super().__init__(ck)
        self.x, self.lo, self.hi, self.op, self.ident = kid.out, lo, hi, op, ident
        self.w = w = hi - lo + 1
        self.C = C = w * (-(-(hi + 1) // w))  # ring capacity: >= hi + 1 and a multiple of w
        N = ck.N
        self.xb = np.full((w, N), ident)  # the current block's raw values
        self.pre = np.full((C, N), ident)  # prefix aggregates (restarted at block starts and step 0)
        self.suf = np.full((C, N), ident)  # suffix aggregates of completed blocks
        self.arw = np.arange(w)[:, None]

    def fast(self, ck):
        x, g, w, C, op, out = self.x, ck.g, self.w, self.C, self.op, self.out
        r = g % w
        self.xb[r] = x
        p = self.pre[g % C]
        if r == 0:
            p[...] = x
        else:
            op(self.pre[(g - 1) % C], x, out=p)
            if ck.tmin == 0:
                np.copyto(p, x, where=ck.t == 0)
        if r == w - 1:  # block complete: its suffix aggregates, once per w steps
            base = (g - w + 1) % C
            self.suf[base: base + w] = op.accumulate(self.xb[::-1], axis=0)[::-1]
        end = g - self.lo
        pe = self.pre[end % C]
        if ck.tmin >= self.hi:  # steady state: every window is [g - hi, g - lo]
            s = g - self.hi
            if s // w != end // w:
                op(self.suf[s % C], pe, out=out)
            else:
                out[...] = pe
            return
        s = np.maximum(ck.start, g - self.hi)
        split = (s // w) != (end // w)
        if split.any():
            np.copyto(out, np.where(split, op(self.suf[s % C, ck.cols], pe), pe))
        else:
            out[...] = pe
        if ck.tmin < self.lo:
            out[ck.t < self.lo] = self.ident

    def slow(self, ck):
        x, n, t, cols, w, C, op = self.x, ck.n_new, ck.t, ck.cols, self.w, self.C, self.op
        r = n % w
        self.xb[r, cols] = x
        pre = op(self.pre[(n - 1) % C, cols], x)
        np.copyto(pre, x, where=(r == 0) | (t == 0))
        self.pre[n % C, cols] = pre
        done = np.flatnonzero(r == w - 1)
        if done.size:  # blocks completing in these columns: their suffix aggregates
            suf = op.accumulate(self.xb[::-1, done], axis=0)[::-1]
            base = (n[done] - (w - 1)) % C
            self.suf[base[None, :] + self.arw, done[None, :]] = suf
        end = n - self.lo
        s = np.maximum(ck.start, n - self.hi)
        res = self.pre[end % C, cols]
        split = (s // w) != (end // w)
        if split.any():
            res = np.where(split, op(self.suf[s % C, cols], res), res)
        res[t < self.lo] = self.ident
        self.out[...] = res


class _SinceUnbounded(_Op):
    """Strict unbounded since: S(t) = max(ψ(t), min(φ(t), S(t-1))), S(-1) = bottom."""

    def __init__(self, left, right, ck):
        super().__init__(ck)
        self.phi, self.psi = left.out, right.out
        self.out.fill(-INF)  # S itself

    def fast(self, ck):
        S, psi = self.out, self.psi
        np.minimum(self.phi, S, out=S)
        np.maximum(psi, S, out=S)
        if ck.tmin == 0:
            np.copyto(S, psi, where=ck.t == 0)

    def slow(self, ck):
        S = np.maximum(self.psi, np.minimum(self.phi, self.out))
        np.copyto(S, self.psi, where=ck.t == 0)
        commit(self.out, S, ck.mask)


def future_name(node) -> Optional[str]:
    """The first future operator in ``node`` (pre-order), as text, or None."""
    if isinstance(node, ir.FUTURE_OPERATORS):
        return f"{type(node).__name__.lower()}{node.interval}"
    for c in ir.children(node):
        name = future_name(c)
        if name:
            return name
    return None


class Graph(ir.NodeCompiler):
    """A compiled, topologically ordered list of online operators for several causal roots,
    over the ``L * B`` columns of ``ck`` (both lanes in one pass)."""

    def __init__(self, roots, ck: Clock):
        self.ck = ck
        self.ops: list[_Op] = []
        self._memo: dict[int, tuple[object, _Op]] = {}
        self.outputs = [self._compile(r) for r in roots]
        work = [op for op in self.ops if not isinstance(op, _ConstOp)]
        # Atoms depend on the states only: they can run first, or be loaded with precomputed values
        # (``step_and_restart``); ``*_rest`` are the other operators, in topological order.
        self.atoms = [op for op in work if isinstance(op, _AtomOp)]
        self.fast_rest = [op.fast for op in work if not isinstance(op, _AtomOp)]
        self.slow_rest = [op.slow for op in work if not isinstance(op, _AtomOp)]

    def _add(self, op) -> _Op:
        self.ops.append(op)
        return op

    def _compile_node(self, node) -> _Op:
        ck = self.ck
        if isinstance(node, ir.Atom):
            return self._add(_AtomOp(node, ck))
        if isinstance(node, ir.Const):
            return self._add(_ConstOp(INF if node.value else -INF, ck))
        if isinstance(node, ir.Not):
            return self._add(_NotOp(self._compile(node.arg), ck))
        if isinstance(node, (ir.And, ir.Or, ir.Implies)):
            a, b = self._compile(node.left), self._compile(node.right)
            if isinstance(node, ir.Implies):
                return self._add(_ImpliesOp(None, a, b, ck))
            return self._add(_BinOp(np.minimum if isinstance(node, ir.And) else np.maximum, a, b, ck))
        if isinstance(node, (ir.Historically, ir.Once)):
            kid = self._compile(node.arg)
            if isinstance(node, ir.Historically):
                op, ident = np.minimum, INF
            else:
                op, ident = np.maximum, -INF
            lo, hi = node.interval.lo, node.interval.hi
            if hi is None:
                return self._add(_PastUnbounded(kid, lo, op, ident, ck))
            return self._add(_PastBounded(kid, lo, hi, op, ident, ck))
        if isinstance(node, ir.Since):
            core = ir.since_unbounded_form(node)
            if core is node:
                return self._add(_SinceUnbounded(self._compile(node.left), self._compile(node.right), ck))
            return self._compile(core)
        if isinstance(node, ir.FUTURE_OPERATORS):
            raise ValueError(
                f"the online monitor needs a causal formula, but {future_name(node)} looks into "
                f"the future; use the past form (historically/once/since), or offline.robustness"
            )
        raise TypeError(f"not a formula node: {node!r}")
