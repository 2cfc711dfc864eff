"""The formula IR: what a checked formula compiles to, and what the evaluators consume.

The checker turns a formula of the language (names resolved, intervals converted to whole steps,
regions and comparisons turned into vectorised atoms) into a tree of these frozen nodes. The
offline evaluator (:mod:`asap_dsl.stl.offline`) and the online monitor
(:mod:`asap_dsl.stl.online`) work on this tree only, never on source text.

Conventions
-----------
* Time is discrete: step indices ``t = 0 .. T-1`` of a trace ``[..., T, n]``.
* Intervals are in whole steps, ``lo <= hi``; ``hi is None`` means unbounded (``inf``).
* Future operators look at ``[t + lo, t + hi]``, past operators at ``[t - hi, t - lo]``,
  both cut at the ends of the trace (an empty window gives ``eventually``/``once`` ``-inf``
  and ``always``/``historically`` ``+inf``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional, Union

import numpy as np

#: A vectorised function of states ``[..., n]`` (any leading shape) returning ``[...]``.
StateFunction = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Interval:
    """A window ``[lo, hi]`` in whole steps; ``hi=None`` is unbounded."""

    lo: int = 0
    hi: Optional[int] = None

    def __post_init__(self) -> None:
        if self.lo < 0 or (self.hi is not None and self.hi < self.lo):
            raise ValueError(f"invalid interval [{self.lo}, {self.hi}]")

    @property
    def bounded(self) -> bool:
        return self.hi is not None

    def __str__(self) -> str:
        return f"[{self.lo}, {'inf' if self.hi is None else self.hi}]"


@dataclass(frozen=True)
class Atom:
    """A predicate over one state.

    ``robustness(states)`` gives the signed margin (positive inside), ``satisfied(states)`` the
    exact Boolean value (strict or non-strict comparison as written). Both take ``[..., n]`` and
    return ``[...]``. ``text`` is the source form, for messages and ``asapc show``.
    """

    text: str
    robustness: StateFunction = field(compare=False)
    satisfied: Callable[[np.ndarray], np.ndarray] = field(compare=False)
    # Bounds of the robustness over the state space (interval analysis), (-inf, inf) if unknown.
    bounds: tuple[float, float] = (-np.inf, np.inf)
    # The region of an `in R` atom (None for a comparison).
    region: Optional[str] = None
    # A comparison's margin as an expression (asap_dsl.ast), for solvers that need it symbolically.
    margin: Optional[object] = field(default=None, compare=False, repr=False)
    # A comparison's operator (<, <=, >, >=), which with the margin gives its Boolean value
    # (the compiled step needs both); None for a region atom.
    op: Optional[str] = field(default=None, compare=False, repr=False)
    # ``row -> (robustness, satisfied)`` on one state of Python floats (the batch-1 monitor);
    # None: the vectorised functions are used on a batch of one.
    scalar: Optional[Callable] = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class Const:
    """``true`` (robustness +inf) or ``false`` (-inf)."""

    value: bool


@dataclass(frozen=True)
class Not:
    arg: "Formula"


@dataclass(frozen=True)
class _Pair:
    """The fields of the binary Boolean operators (each class stays distinct: equality and
    ``isinstance`` tell ``And`` from ``Or``)."""

    left: "Formula"
    right: "Formula"


@dataclass(frozen=True)
class And(_Pair):
    pass


@dataclass(frozen=True)
class Or(_Pair):
    pass


@dataclass(frozen=True)
class Implies(_Pair):
    pass


@dataclass(frozen=True)
class _Window:
    """The fields of the unary temporal operators: a window and one argument."""

    interval: Interval
    arg: "Formula"


@dataclass(frozen=True)
class Always(_Window):
    """Future: minimum over ``[t + lo, t + hi]``."""


@dataclass(frozen=True)
class Eventually(_Window):
    """Future: maximum over ``[t + lo, t + hi]``."""


@dataclass(frozen=True)
class Historically(_Window):
    """Past: minimum over ``[t - hi, t - lo]``."""


@dataclass(frozen=True)
class Once(_Window):
    """Past: maximum over ``[t - hi, t - lo]``."""


@dataclass(frozen=True)
class _Between:
    """The fields of the binary temporal operators: a window and two arguments."""

    interval: Interval
    left: "Formula"
    right: "Formula"


@dataclass(frozen=True)
class Until(_Between):
    """Future: ``left`` holds until ``right`` holds at some ``t' in [t + lo, t + hi]``."""


@dataclass(frozen=True)
class Since(_Between):
    """Past: ``right`` held at some ``t' in [t - hi, t - lo]`` and ``left`` ever since."""


Formula = Union[Atom, Const, Not, And, Or, Implies, Always, Eventually, Historically, Once, Until, Since]

FUTURE_OPERATORS = (Always, Eventually, Until)
PAST_OPERATORS = (Historically, Once, Since)
UNARY_TEMPORAL = (Always, Eventually, Historically, Once)
BINARY_TEMPORAL = (Until, Since)


def children(node: Formula) -> tuple[Formula, ...]:
    """The direct sub-formulas of ``node``."""
    if isinstance(node, (Atom, Const)):
        return ()
    if isinstance(node, (Not, Always, Eventually, Historically, Once)):
        return (node.arg,)
    return (node.left, node.right)


def operands(node: Formula) -> list[Formula]:
    """The operands of the chain of ``and`` (or of ``or``) at ``node``, in order: the leaves of
    the largest subtree of that one operator (``[node]`` for any other node)."""
    if not isinstance(node, (And, Or)):
        return [node]
    cls, out, stack = type(node), [], [node]
    while stack:
        n = stack.pop()
        if type(n) is cls:
            stack += [n.right, n.left]
        else:
            out.append(n)
    return out


def balanced(cls: type, items: list[Formula]) -> Formula:
    """``items[0] cls items[1] cls ...`` (``And`` or ``Or``) as a tree about log2(n) deep: min and
    max are associative, so any grouping has the same value, and evaluators walk trees.

    Items of the same operator (a chain built earlier, a formula used in a chain) are opened
    along their left edge only, into subtrees kept whole, which are then merged like the digits
    of a binary counter by depth (a tree absorbs its left neighbour while that is not deeper).
    Extending a chain of n operands by one builds O(log n) new nodes: 20,000 formulas each
    defined through the previous one cost linear time, not quadratic."""
    blocks: list[Formula] = []
    seen: set[int] = set()
    for item in items:
        spine, n = [], item
        while type(n) is cls:  # the left edge: each n.right is a whole subtree, right to left
            spine.append(n.right)
            n = n.left
        spine.append(n)
        for block in reversed(spine):
            if id(block) not in seen:  # a and a is a: a shared formula once
                seen.add(id(block))
                blocks.append(block)
    stack: list[tuple[Formula, int]] = []  # (tree, depth), depths strictly decreasing
    for block in blocks:
        tree, depth = block, _depth(block)
        while stack and stack[-1][1] <= depth:
            left, d = stack.pop()
            depth = max(d, depth) + 1
            tree = _join(cls, left, tree, depth)
        stack.append((tree, depth))
    # Folded from the left (the deepest first): at most log2(n) levels above the deepest tree,
    # and the next call opens this fold back into the same trees along its left edge.
    tree, depth = stack[0]
    for right, d in stack[1:]:
        depth = max(depth, d) + 1
        tree = _join(cls, tree, right, depth)
    return tree


def _join(cls: type, left: Formula, right: Formula, depth: int) -> Formula:
    node = cls(left, right)
    object.__setattr__(node, "_depth", depth)  # kept for the next balanced(): no walk to find it
    return node


def _depth(node: Formula) -> int:
    known = getattr(node, "_depth", None)
    return known if known is not None else measure(node)[0]


def measure(node: Formula, memo: Optional[dict] = None) -> tuple[int, int]:
    """(depth, size) of ``node`` as the evaluators see it: operators on the longest path to an
    atom, and nodes counted as a tree (a formula used twice counts twice). Linear in the shared
    structure (``memo``: id -> (node, depth, size), reusable across calls) and without recursion."""
    memo = {} if memo is None else memo
    stack = [(node, False)]
    while stack:
        n, expanded = stack.pop()
        if id(n) in memo:
            continue
        kids = children(n)
        if kids and not expanded:
            stack.append((n, True))
            stack.extend((c, False) for c in kids if id(c) not in memo)
            continue
        d = 1 + max((memo[id(c)][1] for c in kids), default=-1)
        size = 1 + sum(memo[id(c)][2] for c in kids)
        memo[id(n)] = (n, d, size)
    _, d, size = memo[id(node)]
    return d, size


def positive_regions(node: Formula) -> tuple[str, ...]:
    """The regions whose `in R` atoms occur positively in ``node`` (not under an odd number of
    negations; the left side of ``->`` counts as negated), in order of first occurrence. What
    the formula asks to be *in*, which lint compares with ``avoid`` and the distance reward
    measures to. Linear in the shared structure (formulas used twice are walked once)."""
    out: dict[str, None] = {}
    seen: set[tuple[int, bool]] = set()
    stack = [(node, True)]
    while stack:
        n, positive = stack.pop()
        if (id(n), positive) in seen:
            continue
        seen.add((id(n), positive))
        if isinstance(n, Atom):
            if positive and n.region is not None:
                out.setdefault(n.region)
        elif isinstance(n, Not):
            stack.append((n.arg, not positive))
        elif isinstance(n, Implies):
            stack += [(n.right, positive), (n.left, not positive)]
        else:
            stack.extend((c, positive) for c in reversed(children(n)))
    return tuple(out)


def is_causal(node: Formula) -> bool:
    """True when no future operator occurs: the value at t depends on steps <= t only."""
    return not isinstance(node, FUTURE_OPERATORS) and all(is_causal(c) for c in children(node))


def horizon(node: Formula) -> float:
    """How many steps past ``t`` the value at ``t`` may look (``inf`` if unbounded)."""
    own = 0.0
    if isinstance(node, FUTURE_OPERATORS):
        own = float("inf") if node.interval.hi is None else float(node.interval.hi)
    return own + max((horizon(c) for c in children(node)), default=0.0)


def history(node: Formula) -> float:
    """How many steps before ``t`` the value at ``t`` may look (``inf`` if unbounded)."""
    own = 0.0
    if isinstance(node, PAST_OPERATORS):
        own = float("inf") if node.interval.hi is None else float(node.interval.hi)
    return own + max((history(c) for c in children(node)), default=0.0)


def to_text(node: Formula) -> str:
    """A fully parenthesised rendering, for messages and ``asapc show``."""
    if isinstance(node, Atom):
        return node.text
    if isinstance(node, Const):
        return "true" if node.value else "false"
    if isinstance(node, Not):
        return f"not {_wrap(node.arg)}"
    if isinstance(node, (And, Or)):  # a chain, however it is grouped: a and b and c
        return f" {type(node).__name__.lower()} ".join(_wrap(c) for c in operands(node))
    if isinstance(node, Implies):
        return f"{_wrap(node.left)} -> {_wrap(node.right)}"
    if isinstance(node, UNARY_TEMPORAL):
        name = type(node).__name__.lower()
        return f"{name}{node.interval} {_wrap(node.arg)}"
    name = type(node).__name__.lower()
    return f"{_wrap(node.left)} {name}{node.interval} {_wrap(node.right)}"


def _wrap(node: Formula) -> str:
    text = to_text(node)
    return text if isinstance(node, (Atom, Const)) else f"({text})"


def cap_past_windows(node: Formula, steps: int) -> Formula:
    """The same formula for traces of at most ``steps + 1`` samples (t = 0 .. steps), with no past
    window longer than they can be: ``[a, b]`` with ``b > steps`` becomes ``[a, inf)`` (both reach
    back to t = 0), and a window that starts before t = 0 at every t (``a > steps``) is always
    empty, a constant. Exact on such traces, and online monitors then need memory in proportion to
    the episode, never to a window written as 1e9 steps.
    """
    if isinstance(node, (Atom, Const)):
        return node
    if isinstance(node, Not):
        return Not(cap_past_windows(node.arg, steps))
    if isinstance(node, (And, Or, Implies)):
        return type(node)(cap_past_windows(node.left, steps), cap_past_windows(node.right, steps))
    iv = node.interval
    if isinstance(node, PAST_OPERATORS):
        if iv.lo > steps:  # empty window: once/since never hold, historically always does
            return Const(isinstance(node, Historically))
        if iv.hi is not None and iv.hi > steps:
            iv = Interval(iv.lo, None)
    if isinstance(node, UNARY_TEMPORAL):
        return type(node)(iv, cap_past_windows(node.arg, steps))
    return type(node)(iv, cap_past_windows(node.left, steps), cap_past_windows(node.right, steps))


class NodeCompiler:
    """Compiles a formula node by node, a node shared by several parents once: a subclass gives
    ``_compile_node(node)`` (which calls ``_compile`` on the children) and sets ``_memo = {}``.
    The memo holds each node with its result, so that ids stay unique while it lives (rewritten
    nodes, such as :func:`since_unbounded_form`'s, included)."""

    _memo: dict

    def _compile_node(self, node: Formula):
        raise NotImplementedError

    def _compile(self, node: Formula):
        hit = self._memo.get(id(node))
        if hit is not None:
            return hit[1]
        out = self._compile_node(node)
        self._memo[id(node)] = (node, out)
        return out


def since_unbounded_form(node: Since) -> Formula:
    """``node`` over the unbounded strict since only, as the online monitors evaluate it::

        φ S[a,b] ψ  =  H[0,a-1] φ  and  O[a,a]( O[0,b-a] ψ  and  φ S ψ )

    (the first conjunct left out for ``a = 0``, ``O[0,b-a] ψ`` for ``b = inf``). ``node`` itself
    when it already is ``φ S[0, inf) ψ``."""
    lo, hi = node.interval.lo, node.interval.hi
    if lo == 0 and hi is None:
        return node
    core: Formula = Since(Interval(0, None), node.left, node.right)
    if hi is not None:
        core = And(Once(Interval(0, hi - lo), node.right), core)
    if lo > 0:
        core = And(Historically(Interval(0, lo - 1), node.left), Once(Interval(lo, lo), core))
    return core
