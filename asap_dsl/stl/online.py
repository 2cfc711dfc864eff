"""Online, batched STL monitors over the formula IR, equal to the offline evaluator at every step.

Public API
----------
``Monitor(node, batch, *, satisfaction=True, n_state=None)``
    For **causal** formulas (atoms, boolean operators, ``historically``/``once``/``since`` with
    bounded or unbounded intervals). ``update(states [B, n], mask=None) -> [B]`` appends one state
    to every trace of the batch and returns ρ(s̄, t, φ) at the newest step t (float64), exactly
    ``offline.robustness(φ, trace so far)[..., t]``. With a bool ``[B]`` ``mask`` only the masked
    entries advance by one step (the rows of ``states`` elsewhere are ignored and may hold
    anything); the others keep their state, their ``t`` and their last returned values. After an
    update, ``.robustness`` holds the returned array and ``.satisfied`` the Boolean semantics
    (s̄, t) ⊨ φ at that step (computed exactly from the atoms' ``satisfied``, not by the sign of ρ;
    pass ``satisfaction=False`` to skip that work, then ``.satisfied`` raises). ``.t`` is the
    per-entry step index of the newest state (``-1`` before the first update of an entry).
    ``reset(mask=None)`` starts a new trace for every entry (or those where the bool ``[B]`` mask
    is True): their next ``update`` is step 0. Resets cost O(1) per entry: nothing is cleared.
    An autoresetting vector env does ``reset(done)`` then ``update(s0, mask=done)``.
    ``update_and_restart(states, done, cand)`` does ``update(states)``, ``reset(done)`` and
    ``update(cand, mask=done)`` with the atoms evaluated once on the reached and restart states
    together (the atoms' fixed per-call cost dominates at env batch sizes); it returns ρ (and ⊨)
    of the reached states.
``PrefixMonitor(node, batch, *, satisfaction=True, n_state=None)``
    For boolean combinations of ``eventually[a, b] ψ``, ``always[a, b] ψ`` and ``ψ1 until[a, b] ψ2``
    with causal ψ's, and of causal parts (taken at t = 0). ``update`` returns the robustness **at
    time 0 of the prefix** s_0..s_t (windows cut at the end of the prefix), i.e. exactly
    ``offline.robustness(φ, prefix)[..., 0]``: running max/min, frozen once the window has closed.
    Same ``update(states, mask=None)``, ``.robustness``, ``.satisfied``, ``.t``, ``reset`` as
    ``Monitor``. This is what the ``rho`` reward of
    ``eventually[0, D] asap and always[0, D] not avoid`` needs every step.
``monitor_for(node, batch, **kw)``
    ``Monitor`` for a causal formula, ``PrefixMonitor`` where that applies, else ``ValueError``.

Cost: O(1) amortised per node per step, vectorised over the batch (no per-entry Python objects).

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

__all__ = ["Monitor", "MonitorValues", "PrefixMonitor", "monitor_for"]

_INF = np.inf


# --------------------------------------------------------------------------------------------
# The clock: per-column step counters and starts; a scalar counter while they are all equal.
# --------------------------------------------------------------------------------------------


class _Clock:
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


def _commit(state: np.ndarray, new: np.ndarray, mask) -> None:
    if mask is None:
        state[...] = new
    else:
        np.copyto(state, new, where=mask)


# --------------------------------------------------------------------------------------------
# Online operators. Each writes its value at the newest step into ``self.out`` ([N] float64).
# ``fast(ck)`` runs on an aligned clock without a mask, ``slow(ck)`` anywhere.
# --------------------------------------------------------------------------------------------


class _Op:
    def __init__(self, ck: _Clock):
        self.out = np.empty(ck.N)

    def slow(self, ck):
        self.fast(ck)


class _AtomOp(_Op):
    def __init__(self, atom: ir.Atom, ck: _Clock):
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
        _commit(self.out, new, ck.mask)


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
        self.out.fill(-_INF)  # S itself

    def fast(self, ck):
        S, psi = self.out, self.psi
        np.minimum(self.phi, S, out=S)
        np.maximum(psi, S, out=S)
        if ck.tmin == 0:
            np.copyto(S, psi, where=ck.t == 0)

    def slow(self, ck):
        S = np.maximum(self.psi, np.minimum(self.phi, self.out))
        np.copyto(S, self.psi, where=ck.t == 0)
        _commit(self.out, S, ck.mask)


def _future_name(node) -> Optional[str]:
    """The first future operator in ``node`` (pre-order), as text, or None."""
    if isinstance(node, ir.FUTURE_OPERATORS):
        return f"{type(node).__name__.lower()}{node.interval}"
    for c in ir.children(node):
        name = _future_name(c)
        if name:
            return name
    return None


class _Graph(ir.NodeCompiler):
    """A compiled, topologically ordered list of online operators for several causal roots,
    over the ``L * B`` columns of ``ck`` (both lanes in one pass)."""

    def __init__(self, roots, ck: _Clock):
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
            return self._add(_ConstOp(_INF if node.value else -_INF, ck))
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
                op, ident = np.minimum, _INF
            else:
                op, ident = np.maximum, -_INF
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
                f"the online monitor needs a causal formula, but {_future_name(node)} looks into "
                f"the future; use the past form (historically/once/since), or offline.robustness"
            )
        raise TypeError(f"not a formula node: {node!r}")


# --------------------------------------------------------------------------------------------
# Public monitors
# --------------------------------------------------------------------------------------------


class MonitorValues:
    """What every online monitor shows after an update (the batched monitors here and the
    batch-1 :class:`asap_dsl.stl.scalar.ScalarMonitor`): ``_rob``, ``_sat`` and ``_track_sat`` are
    set by the monitor."""

    _rob: np.ndarray
    _sat: np.ndarray
    _track_sat: bool

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


class _Base(MonitorValues):
    def __init__(self, batch: int, satisfaction: bool, n_state: Optional[int]):
        if not isinstance(batch, (int, np.integer)) or batch < 1:
            raise ValueError(f"batch must be a positive integer; got {batch!r}")
        self.batch = int(batch)
        self.n_state = n_state
        self._track_sat = bool(satisfaction)
        self._clock = _Clock(self.batch, 2 if self._track_sat else 1)
        self._rob = np.full(self.batch, np.nan)
        self._sat = np.zeros(self.batch, dtype=bool)

    @property
    def t(self) -> np.ndarray:
        """Per-entry step index of the newest state (-1 before an entry's first update)."""
        return self._clock.t[: self.batch].copy()

    def _check_mask(self, mask, what: str):
        if mask is None:
            return None
        m = np.asarray(mask)
        if m.shape != (self.batch,) or m.dtype != np.bool_:
            raise ValueError(f"{what} mask must be a bool array of shape ({self.batch},); got {m.dtype} {m.shape}")
        return m

    def reset(self, mask=None) -> None:
        """Start new traces: all entries, or those where ``mask`` (bool ``[B]``) is True."""
        m = self._check_mask(mask, "reset")
        self._clock.reset(None if m is None else self._clock.tile(m))

    def _check_states(self, states, mask=None) -> np.ndarray:
        s = np.asarray(states, dtype=np.float64)
        if s.ndim != 2 or s.shape[0] != self.batch:
            raise ValueError(f"states must have shape [{self.batch}, n_state]; got {s.shape}")
        if self.n_state is not None and s.shape[1] != self.n_state:
            raise ValueError(f"states have {s.shape[1]} state component(s); expected {self.n_state}")
        if mask is not None:  # rows of entries that do not advance are ignored
            s = np.where(mask[:, None], s, 0.0)
        if not np.isfinite(s).all():
            b, i = (int(v) for v in np.argwhere(~np.isfinite(s))[0])
            raise ValueError(
                f"states contain a non-finite value ({s[b, i]}) at batch index {b}, state component {i}"
            )
        return s

    def _step(self, states, mask, load=None):
        """Validate, advance the clock, evaluate the atoms (or ``load()`` their precomputed values:
        then ``states`` is not read) and run ``self._run(fast)``; returns the [N] result."""
        m = self._check_mask(mask, "update")
        if m is not None and m.all():
            m = None
        s = self._check_states(states, m) if load is None else None
        ck = self._clock
        fast = m is None and ck.aligned
        if fast:
            ck.fast_tick(s)
        else:
            if m is not None and not m.any():
                return None, m
            ck.slow_begin(s, None if m is None else ck.tile(m))
        if load is None:
            for a in self._graph.atoms:
                a.fast(ck)
        else:
            load()
        res = self._run(ck, fast)
        if not fast:
            ck.slow_end()
        B = self.batch
        if m is None:
            self._rob = res[:B].copy()
            if self._track_sat:
                self._sat = res[B:] > 0.0
        else:
            self._rob = np.where(m, res[:B], self._rob)
            if self._track_sat:
                self._sat = np.where(m, res[B:] > 0.0, self._sat)
        return res, m

    def update_and_restart(self, states, done, cand):
        """One autoreset env step in one call: ``update(states)``, then ``reset(done)`` and
        ``update(cand, mask=done)`` (only the ``done`` rows of ``cand [B, n]`` are read), with every
        atom evaluated **once**, on the reached states and the restart states together; the window
        logic then runs for the two updates from those values. Returns ``(rho, sat)`` of the first
        update (the reached states; ``sat`` is None with ``satisfaction=False``); afterwards
        ``.robustness``, ``.satisfied`` and ``.t`` are those of the restarted monitor, exactly as
        after the three separate calls."""
        m = self._check_mask(done, "restart")
        s = self._check_states(states)
        if m is None or not m.any():
            self._step(s, None)
            return self._rob, (self._sat if self._track_sat else None)
        rows = self._check_states(cand, m)[m]
        B, atoms = self.batch, self._graph.atoms
        both = np.concatenate([s, rows])
        vals = [a.values(both) for a in atoms]

        def load_reached():
            for a, v in zip(atoms, vals):
                a.lanes[...] = v[:, :B]

        def load_restart():  # the other columns keep the reached values: never committed
            for a, v in zip(atoms, vals):
                a.lanes[:, m] = v[:, B:]

        self._step(s, None, load_reached)
        rho, sat = self._rob, (self._sat if self._track_sat else None)
        self._clock.reset(self._clock.tile(m))
        self._step(None, m, load_restart)
        return rho, sat


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
        self._graph = _Graph([node], self._clock)
        self._out = self._graph.outputs[0].out

    def _run(self, ck, fast):  # the atoms' values are already in place
        for f in (self._graph.fast_rest if fast else self._graph.slow_rest):
            f(ck)
        return self._out

    def update(self, states, mask=None) -> np.ndarray:
        """Append ``states [B, n]`` to every trace (or to the entries where the bool ``[B]`` ``mask``
        is True; the others keep their values); return ρ at each newest step, float64 ``[B]``."""
        self._step(states, mask)
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
    """Value at time 0 of one top-level leaf over the prefix, in O(1) per step, both lanes."""

    def __init__(self, kind, node, kids, ck):
        self.kind = kind
        self.kids = [k.out for k in kids]  # the causal graph's outputs this leaf reads
        if kind in ("eventually", "until"):
            init = -_INF
        elif kind == "always":
            init = _INF
        else:
            init = -_INF  # causal: overwritten at t = 0
        self.init = init
        self.acc = np.full(ck.N, init)
        self.hmin = np.full(ck.N, _INF)  # until: min of φ over [0, t)
        if kind != "causal":
            self.lo, self.hi = node.interval.lo, node.interval.hi

    def step(self, ck):
        kind, t, mask = self.kind, ck.t, ck.mask
        first = t == 0
        if kind == "causal":
            _commit(self.acc, np.where(first, self.kids[0], self.acc), mask)
            return self.acc
        acc = np.where(first, self.init, self.acc)
        inwin = t >= self.lo
        if self.hi is not None:
            inwin &= t <= self.hi
        if kind == "until":
            phi, psi = self.kids
            hmin = np.where(first, _INF, self.hmin)
            cand = np.maximum(acc, np.minimum(psi, hmin))
            _commit(self.hmin, np.minimum(hmin, phi), mask)
        else:
            v = self.kids[0]
            cand = np.maximum(acc, v) if kind == "eventually" else np.minimum(acc, v)
        _commit(self.acc, np.where(inwin, cand, acc), mask)
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
        self._graph = _Graph(roots, self._clock)
        outs = self._graph.outputs
        self._leaves = [_PrefixLeaf(kind, leaf, [outs[i] for i in ix], self._clock)
                        for (kind, leaf), ix in zip(leaves, idx)]

    def _combine(self, plan, vals):
        kind = plan[0]
        if kind == "leaf":
            return vals[plan[1]]
        if kind == "not":
            return np.negative(self._combine(plan[1], vals))
        a = self._combine(plan[1], vals)
        b = self._combine(plan[2], vals)
        if kind == "and":
            return np.minimum(a, b)
        if kind == "or":
            return np.maximum(a, b)
        return np.maximum(np.negative(a), b)

    def _run(self, ck, fast):  # the atoms' values are already in place
        for f in (self._graph.fast_rest if fast else self._graph.slow_rest):
            f(ck)
        return self._combine(self._plan, [leaf.step(ck) for leaf in self._leaves])

    def update(self, states, mask=None) -> np.ndarray:
        """Append ``states [B, n]`` (to the masked entries only, with a bool ``[B]`` ``mask``);
        return ρ at time 0 of each prefix s_0..s_t, float64 ``[B]``."""
        self._step(states, mask)
        return self._rob


def monitor_for(node: ir.Formula, batch: int, **kw):
    """``Monitor`` for a causal formula (:class:`asap_dsl.stl.scalar.ScalarMonitor` for a batch
    of one: Python floats, no numpy per step), ``PrefixMonitor`` for top-level future operators
    over causal parts; otherwise ``ValueError`` naming the operator that cannot be monitored."""
    if ir.is_causal(node):
        if batch == 1 and not isinstance(batch, bool):
            from .scalar import ScalarMonitor

            return ScalarMonitor(node, **kw)
        return Monitor(node, batch, **kw)
    return PrefixMonitor(node, batch, **kw)
