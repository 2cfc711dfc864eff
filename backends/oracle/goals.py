"""What the oracle can solve: ``asap`` and ``avoid`` in a normal form over timed literals.

Used by :mod:`asap_dsl.backends.oracle.solver`; the normal form is explained below.
"""

from __future__ import annotations

from typing import Optional

from asap_dsl.stl import ir


class OracleUnsupported(ValueError):
    """The oracle cannot treat this system or task (black box, non-region formula, ...)."""


# --------------------------------------------------------------------------- formulas
# Normal forms over *timed literals*, for a trace of N + 1 states (steps 0..N, judged at N):
# ("lit", atom, positive, back) — the atom holds (or not) at step N - back —, ("and", [..]),
# ("or", [..]), ("const", bool). Past operators with windows unfold into one literal per step of
# the window: historically[a, b] phi at N is phi at every step N-b..N-a (the window cut at step 0);
# once[a, b] phi is phi at one of them. Negation is pushed to the literals.

#: Alternatives (disjuncts of the normal form) the oracle expands at most: each is one NLP per N.
MAX_ALTERNATIVES = 64


def _unsupported(node: ir.Formula, what: str) -> OracleUnsupported:
    return OracleUnsupported(
        f"the oracle does not support {what} (in `{ir.to_text(node)}`): it supports conditions on the "
        "state (regions, comparisons) with not/and/or/->, under historically and once with windows")


_FUTURE = {ir.Always: "always", ir.Eventually: "eventually", ir.Until: "until"}


def _normal(node: ir.Formula, N: Optional[int], positive: bool = True, back: int = 0):
    """Negation normal form of ``node`` at step N of a trace of N + 1 states (``back`` steps
    earlier); ``N=None``: no temporal operator allowed (``avoid``, judged at every step)."""
    if isinstance(node, ir.Atom):
        if node.region is None and node.margin is None:
            raise _unsupported(node, f"the condition `{node.text}`")
        return ("lit", node, positive, back)
    if isinstance(node, ir.Const):
        return ("const", node.value == positive)
    if isinstance(node, ir.Not):
        return _normal(node.arg, N, not positive, back)
    if isinstance(node, ir.Implies):
        return _normal(ir.Or(ir.Not(node.left), node.right), N, positive, back)
    if isinstance(node, (ir.And, ir.Or)):
        is_and = isinstance(node, ir.And) == positive
        return ("and" if is_and else "or", [_normal(c, N, positive, back) for c in ir.operands(node)])
    if isinstance(node, (ir.Historically, ir.Once)):
        name = type(node).__name__.lower()
        if N is None:
            raise _unsupported(node, f"`{name}` in `avoid` (judged at every step on its own)")
        iv = node.interval
        last = N - back if iv.hi is None else min(iv.hi, N - back)
        offsets = range(iv.lo, last + 1)
        every = isinstance(node, ir.Historically) == positive  # historically, or not once
        if not offsets:  # the window lies before step 0: historically holds, once does not
            return ("const", isinstance(node, ir.Historically) == positive)
        return ("and" if every else "or", [_normal(node.arg, N, positive, back + o) for o in offsets])
    if type(node) in _FUTURE:
        raise _unsupported(node, f"the future operator `{_FUTURE[type(node)]}`")
    raise _unsupported(node, f"`{type(node).__name__.lower()}`")


def _dnf(f, limit: int = MAX_ALTERNATIVES) -> list[list[tuple]]:
    """Disjunctive normal form: a list of conjunctions of (atom, positive, back) literals."""
    kind = f[0]
    if kind == "lit":
        return [[(f[1], f[2], f[3])]]
    if kind == "const":
        return [[]] if f[1] else []
    parts = [_dnf(g, limit) for g in f[1]]
    if kind == "or":
        out = [c for p in parts for c in p]
    else:
        out = [[]]
        for p in parts:
            out = [a + b for a in out for b in p]
            if len(out) > limit:
                break
    if len(out) > limit:
        raise OracleUnsupported(f"this `asap` has more than {limit} alternatives once its `or`s and `once`s are "
                                "expanded (one optimisation problem each): shorten the windows of `once`")
    return out


def _literals(f) -> list[tuple]:
    kind = f[0]
    if kind == "lit":
        return [(f[1], f[2], f[3])]
    if kind in ("and", "or"):
        return [lit for g in f[1] for lit in _literals(g)]
    return []


def _flatten_and(f) -> list:
    if f[0] == "and":
        return [h for g in f[1] for h in _flatten_and(g)]
    return [f]
