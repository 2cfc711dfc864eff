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

The compiled operator graph (clocks, windows, the one-pass layout of robustness and
satisfaction) is :mod:`asap_dsl.stl.operators`.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from . import ir
from .operators import INF, Clock, Graph, commit, future_name

__all__ = ["Monitor", "MonitorValues", "PrefixMonitor", "monitor_for"]


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
        self._clock = Clock(self.batch, 2 if self._track_sat else 1)
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
        name = future_name(node)
        if name is not None:
            raise ValueError(
                f"Monitor needs a causal formula, but {name} looks into the future; use the past "
                f"form (historically/once/since), PrefixMonitor for top-level bounded future "
                f"operators, or offline.robustness"
            )
        self.node = node
        self._graph = Graph([node], self._clock)
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
                f"{future_name(node.arg)} is nested inside {type(node).__name__.lower()}{node.interval}"
            )
        leaves.append((type(node).__name__.lower(), node))
        return ("leaf", len(leaves) - 1)
    if isinstance(node, ir.Until):
        for side in (node.left, node.right):
            if not ir.is_causal(side):
                raise ValueError(
                    f"PrefixMonitor supports future operators only at the top of the formula; "
                    f"{future_name(side)} is nested inside until{node.interval}"
                )
        leaves.append(("until", node))
        return ("leaf", len(leaves) - 1)
    # A past operator over a future one.
    raise ValueError(
        f"no online monitor for this formula: {future_name(node)} sits under the past operator "
        f"{type(node).__name__.lower()}; only causal formulas (Monitor) or top-level future "
        f"operators over causal arguments (PrefixMonitor) can be monitored online"
    )


class _PrefixLeaf:
    """Value at time 0 of one top-level leaf over the prefix, in O(1) per step, both lanes."""

    def __init__(self, kind, node, kids, ck):
        self.kind = kind
        self.kids = [k.out for k in kids]  # the causal graph's outputs this leaf reads
        if kind in ("eventually", "until"):
            init = -INF
        elif kind == "always":
            init = INF
        else:
            init = -INF  # causal: overwritten at t = 0
        self.init = init
        self.acc = np.full(ck.N, init)
        self.hmin = np.full(ck.N, INF)  # until: min of φ over [0, t)
        if kind != "causal":
            self.lo, self.hi = node.interval.lo, node.interval.hi

    def step(self, ck):
        kind, t, mask = self.kind, ck.t, ck.mask
        first = t == 0
        if kind == "causal":
            commit(self.acc, np.where(first, self.kids[0], self.acc), mask)
            return self.acc
        acc = np.where(first, self.init, self.acc)
        inwin = t >= self.lo
        if self.hi is not None:
            inwin &= t <= self.hi
        if kind == "until":
            phi, psi = self.kids
            hmin = np.where(first, INF, self.hmin)
            cand = np.maximum(acc, np.minimum(psi, hmin))
            commit(self.hmin, np.minimum(hmin, phi), mask)
        else:
            v = self.kids[0]
            cand = np.maximum(acc, v) if kind == "eventually" else np.minimum(acc, v)
        commit(self.acc, np.where(inwin, cand, acc), mask)
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
        self._graph = Graph(roots, self._clock)
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
