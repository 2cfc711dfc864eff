"""What the oracle can solve: ``asap`` and ``avoid`` in a normal form over timed literals.

The normal form of a formula judged at step N of a trace of N + 1 states (steps 0..N) is a tree
of small records: :class:`Literal` (an atom holds, or not, at step N - back), :class:`AllOf`,
:class:`AnyOf` and :class:`Constant`. Negation is pushed to the literals. Past operators with
windows unfold into one literal per step of the window: ``historically[a, b] phi`` at N is phi at
every step N-b..N-a (the window cut at step 0); ``once[a, b] phi`` is phi at one of them.
:func:`dnf` expands a normal form into its alternatives (conjunctions of literals), one
optimisation problem each; :class:`Goals` holds a task's forms, as the rest of the oracle reads
them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Union

from asap_dsl.stl import ir

__all__ = ["MAX_ALTERNATIVES", "AllOf", "AnyOf", "Constant", "Goals", "Literal", "Normal", "OracleUnsupported",
           "dnf", "flatten_and", "literals", "normal"]


class OracleUnsupported(ValueError):
    """The oracle cannot treat this system or task (black box, non-region formula, ...)."""


#: Alternatives (disjuncts of the normal form) the oracle expands at most: each is one NLP per N.
MAX_ALTERNATIVES = 64


@dataclass(frozen=True)
class Literal:
    """``atom`` holds (``positive``) or does not hold at step N - ``back``."""

    atom: ir.Atom
    positive: bool
    back: int


@dataclass(frozen=True)
class AllOf:
    """Every part holds."""

    parts: tuple["Normal", ...]


@dataclass(frozen=True)
class AnyOf:
    """At least one part holds."""

    parts: tuple["Normal", ...]


@dataclass(frozen=True)
class Constant:
    """Always true or always false (a constant, or a window that lies before step 0)."""

    value: bool


#: A formula in normal form.
Normal = Union[Literal, AllOf, AnyOf, Constant]

#: One alternative of :func:`dnf`: the literals that must all hold.
Conjunction = list[Literal]


def _unsupported(node: ir.Formula, what: str) -> OracleUnsupported:
    return OracleUnsupported(
        f"the oracle does not support {what} (in `{ir.to_text(node)}`): it supports conditions on the "
        "state (regions, comparisons) with not/and/or/->, under historically and once with windows")


_FUTURE = {ir.Always: "always", ir.Eventually: "eventually", ir.Until: "until"}


def normal(node: ir.Formula, N: Optional[int], positive: bool = True, back: int = 0) -> Normal:
    """The normal form of ``node`` (negated unless ``positive``) judged ``back`` steps before step
    N of a trace of N + 1 states.

    :param node: the formula.
    :param N: the step it is judged at; ``None``: no temporal operator allowed (``avoid``, judged
        at every step on its own).
    :param positive: False for the normal form of ``not node``.
    :param back: how many steps before N.
    :raises OracleUnsupported: a part the oracle cannot express (future operators, a condition
        that is neither a region nor a comparison, ``historically`` in ``avoid``), named.
    """
    if isinstance(node, ir.Atom):
        if node.region is None and node.margin is None:
            raise _unsupported(node, f"the condition `{node.text}`")
        return Literal(node, positive, back)
    if isinstance(node, ir.Const):
        return Constant(node.value == positive)
    if isinstance(node, ir.Not):
        return normal(node.arg, N, not positive, back)
    if isinstance(node, ir.Implies):
        return normal(ir.Or(ir.Not(node.left), node.right), N, positive, back)
    if isinstance(node, (ir.And, ir.Or)):
        is_and = isinstance(node, ir.And) == positive
        parts = tuple(normal(c, N, positive, back) for c in ir.operands(node))
        return AllOf(parts) if is_and else AnyOf(parts)
    if isinstance(node, (ir.Historically, ir.Once)):
        name = type(node).__name__.lower()
        if N is None:
            raise _unsupported(node, f"`{name}` in `avoid` (judged at every step on its own)")
        iv = node.interval
        last = N - back if iv.hi is None else min(iv.hi, N - back)
        offsets = range(iv.lo, last + 1)
        every = isinstance(node, ir.Historically) == positive  # historically, or not once
        if not offsets:  # the window lies before step 0: historically holds, once does not
            return Constant(isinstance(node, ir.Historically) == positive)
        parts = tuple(normal(node.arg, N, positive, back + o) for o in offsets)
        return AllOf(parts) if every else AnyOf(parts)
    if type(node) in _FUTURE:
        raise _unsupported(node, f"the future operator `{_FUTURE[type(node)]}`")
    raise _unsupported(node, f"`{type(node).__name__.lower()}`")


def dnf(f: Normal, limit: int = MAX_ALTERNATIVES) -> list[Conjunction]:
    """The disjunctive normal form of ``f``: its alternatives, each a list of literals that must
    all hold (no alternative: ``f`` is false; one empty alternative: true).

    :param f: a normal form.
    :param limit: the most alternatives expanded.
    :raises OracleUnsupported: more than ``limit`` alternatives.
    """
    if isinstance(f, Literal):
        return [[f]]
    if isinstance(f, Constant):
        return [[]] if f.value else []
    parts = [dnf(g, limit) for g in f.parts]
    if isinstance(f, AnyOf):
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


def literals(f: Normal) -> list[Literal]:
    """Every literal of ``f``, in order."""
    if isinstance(f, Literal):
        return [f]
    if isinstance(f, (AllOf, AnyOf)):
        return [lit for g in f.parts for lit in literals(g)]
    return []


def flatten_and(f: Normal) -> list[Normal]:
    """The conjuncts of ``f``, nested conjunctions flattened (``[f]`` when it is not one)."""
    if isinstance(f, AllOf):
        return [h for g in f.parts for h in flatten_and(g)]
    return [f]


class Goals:
    """A task's ``asap`` and ``avoid`` in normal form, as the oracle's parts read them.

    Checked up front: the widest expansion of ``asap`` (at the deadline: the most alternatives)
    and ``avoid`` are in the fragment the oracle supports and name known regions.

    :param task: the task's model (``asap``, ``avoid``, ``deadline``).
    :param regions: the program's regions by name.
    :raises OracleUnsupported: an unsupported part or an unknown region.
    """

    def __init__(self, task, regions: dict):
        self._asap = task.asap
        self._at: dict[int, list[Conjunction]] = {}
        #: The alternatives of ``asap`` at the deadline (the widest windows).
        self.widest = self.at(int(task.deadline))
        #: ``avoid`` in normal form, negated (what must hold at every step), or None.
        self.safe: Optional[Normal] = None if task.avoid is None else normal(task.avoid, None, positive=False)
        for lit in [lit for c in self.widest for lit in c] + (literals(self.safe) if self.safe else []):
            if lit.atom.region is not None and lit.atom.region not in regions:
                raise OracleUnsupported(f"unknown region '{lit.atom.region}'")
        #: What the lower bounds test (a relaxation, hence sound): per alternative, the regions it
        #: must be inside at step N itself. Alternatives at a smaller N are these, or weaker (cut
        #: windows); "outside a region" gives no bound, so negative literals are left out.
        self.regions_now: list[tuple[str, ...]] = [
            tuple(lit.atom.region for lit in conj if lit.back == 0 and lit.atom.region is not None and lit.positive)
            for conj in self.widest]

    def at(self, N: int) -> list[Conjunction]:
        """The alternatives of ``asap`` judged at step N (memoised)."""
        if N not in self._at:
            self._at[N] = dnf(normal(self._asap, N))
        return self._at[N]
