"""Online monitors as numba source: every operator of a formula as a few lines over one entry.

The values are those of the batched monitor (:class:`asap_dsl.stl.online.Monitor`, and
``PrefixMonitor`` for the ``rho`` reward over a whole episode), which equal the offline
evaluator: robustness in lane 0 and satisfaction in lane 1 (+1 / -1 from the atoms, ±inf for
``true``/``false`` and empty windows; not/and/or/min/max on that encoding are the Boolean
operators, ``satisfied = lane 1 > 0``). min/max are numpy's (NaN wins), so a NaN atom poisons
every window that holds it, as in numpy.

Each entry keeps what an operator carries from step to step in its own row of two arrays,
``F[b]`` (float64) and ``I[b]`` (int64), at columns fixed at generation time (:class:`Layout`).
The generated code runs with ``t``, the entry's step (0: its initial state), ``F``, ``I`` and
``b`` in scope; an operator restarts itself at the step its window starts (``t == lo``), so a
restart is an update at ``t = 0`` and nothing is ever cleared.

* ``historically``/``once`` over ``[lo, hi]``: the value delayed by ``lo`` (a ring of ``lo + 1``),
  then a monotone deque (a ring of ``hi - lo + 1``: amortised O(1) per step whatever the window)
  and the step of the newest NaN in it; over ``[lo, inf)`` a running min/max.
* ``since``: the unbounded strict since ``S(t) = max(ψ(t), min(φ(t), S(t-1)))``, bounded
  windows rewritten into it (:func:`asap_dsl.stl.ir.since_unbounded_form`, as the monitors do).
* top-level ``eventually``/``always``/``until`` (prefix formulas): the running value at time 0 of
  the prefix, frozen once the window has closed.
"""

from __future__ import annotations

from typing import Callable, Optional

from ..stl import ir
from .exprs import Body, NotCovered, comparison_atom, mn, mx, region_atom

_NEG, _POS = "(-_INF)", "_INF"


class Layout:
    """The columns of each entry's float row ``F[b]`` and int row ``I[b]``."""

    def __init__(self) -> None:
        self.nf = 0
        self.ni = 0

    def f(self, k: int = 1) -> int:
        """``k`` new float columns; the first one's index."""
        self.nf += k
        return self.nf - k

    def i(self, k: int = 1) -> int:
        """``k`` new int columns; the first one's index."""
        self.ni += k
        return self.ni - k


class MonitorCode:
    """Emits the monitors of several formulas into one function body (atoms shared by object)."""

    def __init__(self, body: Body, layout: Layout, region: Callable[[str], object]):
        self.body, self.layout, self.region = body, layout, region
        self._atoms: dict[int, tuple[object, tuple[str, str]]] = {}
        self._memo: dict[tuple[int, int], tuple[object, str]] = {}
        self._keep: list = []  # rewritten nodes kept alive: their ids stay unique
        self._n = 0

    # ---- public ----------------------------------------------------------------------------
    def causal(self, node: ir.Formula, lanes: int) -> tuple[str, Optional[str]]:
        """(robustness, satisfaction lane or None) of a causal formula at the newest step."""
        rob = self._emit(node, 0)
        return rob, (self._emit(node, 1) if lanes == 2 else None)

    def tracker(self, node: ir.Formula, lanes: int) -> tuple[str, Optional[str]]:
        """What :class:`asap_dsl.rewards.FormulaTracker` reports: the causal value, or for
        top-level future operators the value at time 0 of the prefix (the prefix monitor)."""
        if ir.is_causal(node):
            return self.causal(node, lanes)
        leaves: list = []
        plan = _prefix_plan(node, leaves)
        out = []
        for lane in range(lanes):
            vals = [self._leaf(kind, leaf, lane) for kind, leaf in leaves]
            out.append(self._combine(plan, vals))
        return out[0], (out[1] if lanes == 2 else None)

    # ---- helpers ---------------------------------------------------------------------------
    def _name(self, lane: int) -> str:
        self._n += 1
        return f"{'rs'[lane]}{self._n}"

    def _set(self, lane: int, code: str, extra: int = 0) -> str:
        v = self._name(lane)
        self.body.line(f"{v} = {code}", extra)
        return v

    def _emit(self, node: ir.Formula, lane: int) -> str:
        key = (id(node), lane)
        hit = self._memo.get(key)
        if hit is not None:
            return hit[1]
        v = self._emit_node(node, lane)
        self._memo[key] = (node, v)
        return v

    def _atom(self, node: ir.Atom) -> tuple[str, str]:
        hit = self._atoms.get(id(node))
        if hit is None:
            if node.region is not None:
                vals = region_atom(self.body, self.region(node.region))
            else:
                op = getattr(node, "op", None)
                if op is None:
                    raise NotCovered(f"the comparison {node.text!r} does not carry its operator")
                vals = comparison_atom(self.body, node.margin, op)
            hit = self._atoms[id(node)] = (node, vals)
        return hit[1]

    def _emit_node(self, node: ir.Formula, lane: int) -> str:
        if isinstance(node, ir.Atom):
            return self._atom(node)[lane]
        if isinstance(node, ir.Const):
            return _POS if node.value else _NEG
        if isinstance(node, ir.Not):
            return self._set(lane, f"-{self._emit(node.arg, lane)}")
        if isinstance(node, (ir.And, ir.Or, ir.Implies)):
            a, b = self._emit(node.left, lane), self._emit(node.right, lane)
            if isinstance(node, ir.Implies):
                return self._set(lane, mx(f"-{a}", b))
            return self._set(lane, (mn if isinstance(node, ir.And) else mx)(a, b))
        if isinstance(node, (ir.Historically, ir.Once)):
            return self._window(node, self._emit(node.arg, lane), lane)
        if isinstance(node, ir.Since):
            core = ir.since_unbounded_form(node)
            if core is not node:
                self._keep.append(core)
                return self._emit(core, lane)
            return self._since(self._emit(node.left, lane), self._emit(node.right, lane), lane)
        raise NotCovered(f"no online monitor for {type(node).__name__.lower()} here")

    def _window(self, node, x: str, lane: int) -> str:
        every = isinstance(node, ir.Historically)
        op, ident = (mn, _POS) if every else (mx, _NEG)
        lo, hi = node.interval.lo, node.interval.hi
        L, lay, out = self.body.line, self.layout, self._name(lane)
        d = 0
        v = x
        if lo:  # the value of step t - lo, from a ring of the last lo + 1 values
            ring = lay.f(lo + 1)
            L(f"F[b, {ring} + t % {lo + 1}] = {x}")
            L(f"if t < {lo}:")
            L(f"{out} = {ident}", 1)
            L("else:")
            v = f"_v{out}"
            L(f"{v} = F[b, {ring} + (t - {lo}) % {lo + 1}]", 1)
            d = 1
        if hi is None:  # running min/max from step lo on
            acc = lay.f()
            L(f"if t == {lo}:", d)
            L(f"{out} = {v}", d + 1)
            L("else:", d)
            L(f"{out} = {op(f'F[b, {acc}]', v)}", d + 1)
            L(f"F[b, {acc}] = {out}", d)
            return out
        if hi == lo:
            L(f"{out} = {v}", d)
            return out
        w = hi - lo + 1
        val, idx, hd = lay.f(w), lay.i(w), lay.i(3)  # deque values, their steps; head, size, newest NaN
        sz, nn = hd + 1, hd + 2
        h, s, q, j = f"_h{out}", f"_s{out}", f"_q{out}", f"_j{out}"
        track_nan = lane == 0  # satisfaction is never NaN
        evict = "<=" if not every else ">="
        L(f"if t == {lo}:", d)
        L(f"{h} = 0", d + 1)
        L(f"{s} = 0", d + 1)
        if track_nan:
            L(f"{q} = -_BIG", d + 1)
        L("else:", d)
        L(f"{h} = I[b, {hd}]", d + 1)
        L(f"{s} = I[b, {sz}]", d + 1)
        if track_nan:
            L(f"{q} = I[b, {nn}]", d + 1)
        L(f"while {s} > 0 and I[b, {idx} + {h}] < t - {hi}:", d)  # leaving the window
        L(f"{h} = {h} + 1 if {h} + 1 < {w} else 0", d + 1)
        L(f"{s} -= 1", d + 1)
        e = d
        if track_nan:
            L(f"if {v} != {v}:", d)
            L(f"{q} = t - {lo}", d + 1)
            L("else:", d)
            e = d + 1
        L(f"while {s} > 0:", e)  # values the new one dominates never matter again
        L(f"{j} = {h} + {s} - 1", e + 1)
        L(f"if {j} >= {w}:", e + 1)
        L(f"{j} -= {w}", e + 2)
        L(f"if F[b, {val} + {j}] {evict} {v}:", e + 1)
        L(f"{s} -= 1", e + 2)
        L("else:", e + 1)
        L("break", e + 2)
        L(f"{j} = {h} + {s}", e)
        L(f"if {j} >= {w}:", e)
        L(f"{j} -= {w}", e + 1)
        L(f"F[b, {val} + {j}] = {v}", e)
        L(f"I[b, {idx} + {j}] = t - {lo}", e)
        L(f"{s} += 1", e)
        L(f"I[b, {hd}] = {h}", d)
        L(f"I[b, {sz}] = {s}", d)
        if track_nan:
            L(f"I[b, {nn}] = {q}", d)
            L(f"if {q} >= t - {hi}:", d)
            L(f"{out} = _NAN", d + 1)
            L(f"elif {s} == 0:", d)
        else:
            L(f"if {s} == 0:", d)
        L(f"{out} = {ident}", d + 1)
        L("else:", d)
        L(f"{out} = F[b, {val} + {h}]", d + 1)
        return out

    def _since(self, phi: str, psi: str, lane: int) -> str:
        L, out, S = self.body.line, self._name(lane), self.layout.f()
        L("if t == 0:")
        L(f"{out} = {psi}", 1)
        L("else:")
        L(f"{out} = {mn(phi, f'F[b, {S}]')}", 1)
        L(f"{out} = {mx(psi, out)}", 1)
        L(f"F[b, {S}] = {out}")
        return out

    # ---- prefix formulas -------------------------------------------------------------------
    def _leaf(self, kind: str, node, lane: int) -> str:
        """One top-level leaf of a prefix formula (``_PrefixLeaf`` of the batched monitor)."""
        L, lay, out = self.body.line, self.layout, self._name(lane)
        acc = lay.f()
        if kind == "causal":  # its value at t = 0, frozen
            kid = self._emit(node, lane)
            L("if t == 0:")
            L(f"F[b, {acc}] = {kid}", 1)
            L(f"{out} = F[b, {acc}]")
            return out
        lo, hi = node.interval.lo, node.interval.hi
        inwin = f"t >= {lo}" + ("" if hi is None else f" and t <= {hi}")
        if kind == "until":
            phi, psi = self._emit(node.left, lane), self._emit(node.right, lane)
            hm, m = lay.f(), f"_m{out}"
            L("if t == 0:")
            L(f"{out} = {_NEG}", 1)
            L(f"{m} = {_POS}", 1)
            L("else:")
            L(f"{out} = F[b, {acc}]", 1)
            L(f"{m} = F[b, {hm}]", 1)
            L(f"if {inwin}:")
            L(f"{m}p = {mn(psi, m)}", 1)
            L(f"{out} = {mx(out, m + 'p')}", 1)
            L(f"F[b, {hm}] = {mn(m, phi)}")
            L(f"F[b, {acc}] = {out}")
            return out
        v = self._emit(node.arg, lane)
        init, op = (_NEG, mx) if kind == "eventually" else (_POS, mn)
        L("if t == 0:")
        L(f"{out} = {init}", 1)
        L("else:")
        L(f"{out} = F[b, {acc}]", 1)
        L(f"if {inwin}:")
        L(f"{out} = {op(out, v)}", 1)
        L(f"F[b, {acc}] = {out}")
        return out

    def _combine(self, plan, vals: list[str]) -> str:
        kind = plan[0]
        if kind == "leaf":
            return vals[plan[1]]
        if kind == "not":
            return self._set(0, f"-{self._combine(plan[1], vals)}")
        a, b = self._combine(plan[1], vals), self._combine(plan[2], vals)
        if kind == "and":
            return self._set(0, mn(a, b))
        if kind == "or":
            return self._set(0, mx(a, b))
        return self._set(0, mx(f"-{a}", b))


def _prefix_plan(node, leaves: list):
    """The Boolean skeleton over the leaves of a prefix formula (as the batched monitor's)."""
    from ..stl.online import _prefix_plan as plan

    return plan(node, leaves)
