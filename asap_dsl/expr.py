"""Expressions compiled once into vectorised callables, for three backends.

One code generator turns checked expression ASTs into a Python function; the backend decides
what the function computes with:

* ``numpy``    — batched evaluation, each variable an array over the batch;
* ``casadi``   — symbolic expressions for the optimal-control oracle;
* ``interval`` — sound range enclosures over a box (:mod:`asap_dsl.intervals`).

The generated function takes ``(S, A)``: indexable sequences of the state and action components
(``S[i]``), evaluates the ``let`` definitions it needs once, and returns a tuple of results.
Constants are folded to numbers at compile time. Nothing is parsed or interpreted per call.
"""

from __future__ import annotations

import functools
import math
import operator
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Callable, Iterable, Mapping, Optional, Sequence

import numpy as np

from . import ast, intervals

#: The functions of the language and how many arguments each takes (None: one or more).
FUNCTION_ARITY: dict[str, Optional[int]] = {
    "sin": 1, "cos": 1, "tan": 1, "asin": 1, "acos": 1, "atan": 1, "atan2": 2,
    "sinh": 1, "cosh": 1, "tanh": 1, "exp": 1, "log": 1, "sqrt": 1, "abs": 1,
    "min": None, "max": None, "norm": None, "clip": 3,
}

BUILTIN_CONSTANTS = {"pi": math.pi, "e": math.e}

#: A comparison's operator -> the backends' name of it (``_F.lt`` ...).
COMPARE_NAMES = {"<": "lt", "<=": "le", ">": "gt", ">=": "ge", "==": "eq", "!=": "ne"}


def _folded(pairwise: Callable) -> Callable:
    """``min``/``max`` of one or more arguments from their two-argument form, left to right."""
    def fold(*xs):
        return functools.reduce(pairwise, xs)
    return fold


def _np_norm(*xs):
    return np.sqrt(sum(np.square(x) for x in xs))


def _clipped(lower: Callable, upper: Callable) -> Callable:
    """``clip(x, lo, hi)`` as ``min(max(x, lo), hi)`` with the backend's own min and max: one
    definition, so that every backend (and the compiled step) computes the same value."""
    return lambda x, lo, hi: lower(upper(x, lo), hi)


def _tests(and_: Callable, or_: Callable, not_: Callable, where: Callable) -> dict:
    """What a conditional (``if c then a else b``) computes with: comparisons (Python's operators,
    which numpy arrays and CasADi symbols overload), ``and``/``or``/``not`` and the choice."""
    return dict(lt=operator.lt, le=operator.le, gt=operator.gt, ge=operator.ge, eq=operator.eq, ne=operator.ne,
                and_=and_, or_=or_, not_=not_, where=where)


NUMPY = SimpleNamespace(
    sin=np.sin, cos=np.cos, tan=np.tan, asin=np.arcsin, acos=np.arccos, atan=np.arctan,
    atan2=np.arctan2, sinh=np.sinh, cosh=np.cosh, tanh=np.tanh, exp=np.exp, log=np.log,
    sqrt=np.sqrt, abs=np.abs, min=_folded(np.minimum), max=_folded(np.maximum), norm=_np_norm, pow=np.power,
    clip=_clipped(np.minimum, np.maximum),
    **_tests(np.logical_and, np.logical_or, np.logical_not, np.where),
)

INTERVAL = SimpleNamespace(**intervals.FUNCTIONS, **intervals.TESTS, pow=lambda a, b: intervals.Interval.of(a) ** b)


def casadi_namespace() -> SimpleNamespace:
    import casadi as ca  # imported only when the oracle asks for it

    return SimpleNamespace(
        sin=ca.sin, cos=ca.cos, tan=ca.tan, asin=ca.asin, acos=ca.acos, atan=ca.atan,
        atan2=ca.atan2, sinh=ca.sinh, cosh=ca.cosh, tanh=ca.tanh, exp=ca.exp, log=ca.log,
        sqrt=ca.sqrt, abs=ca.fabs, min=_folded(ca.fmin), max=_folded(ca.fmax),
        norm=lambda *xs: ca.sqrt(sum(x * x for x in xs)), pow=lambda a, b: a ** b,
        # Non-smooth where it switches: IPOPT sees a kink (clip) or a jump (if), see docs/oracle.md.
        clip=_clipped(ca.fmin, ca.fmax), **_tests(ca.logic_and, ca.logic_or, ca.logic_not, ca.if_else),
    )


@dataclass(frozen=True)
class Symbols:
    """What each name of an expression means.

    ``consts`` are folded; ``states``/``actions`` map names to component indices; ``lets`` map
    names to their (checked) defining expressions, evaluated in the order given.
    """

    consts: Mapping[str, float]
    states: Mapping[str, int]
    actions: Mapping[str, int]
    lets: Mapping[str, ast.Expr]


class LetWalker:
    """A post-order walk of an expression with an explicit stack (its depth is the user's), in
    which a let is walked once, the first time it is met: subclasses give ``_leaf(node)`` (a
    value, or None for a node with children), ``_children(node)`` and ``_combine(node, values)``,
    and record a let's value in ``self.lets`` when combining its Name. ``_children`` is that of
    an arithmetic expression (a let's child is its body); ``_not_arithmetic(node)`` says what
    another node has (by default: it is an error)."""

    lets: dict
    sym: Symbols

    def _children(self, e: ast.Expr) -> list[ast.Expr]:
        if isinstance(e, ast.Name):  # a let
            return [self.sym.lets[e.id]]
        if isinstance(e, ast.Unary):
            return [e.arg]
        if isinstance(e, ast.Binary):
            return [e.left, e.right]
        if isinstance(e, ast.Call):
            return list(e.args)
        if isinstance(e, ast.Conditional):  # the test's nodes are walked like numbers' (they are over numbers)
            return [e.test, e.then_, e.else_]
        if isinstance(e, (ast.Compare, ast.Logic)):
            return [e.left, e.right]
        if isinstance(e, ast.Not):
            return [e.arg]
        return self._not_arithmetic(e)

    def _not_arithmetic(self, e: ast.Expr) -> list[ast.Expr]:
        raise TypeError(f"not an arithmetic expression: {type(e).__name__}")

    def walk(self, root: ast.Expr):
        done: list = []               # values of finished nodes, in post-order
        stack: list[tuple[ast.Expr, int]] = [(root, -1)]  # (node, values before its children); -1: not expanded
        while stack:
            node, mark = stack.pop()
            if mark < 0:
                leaf = self._leaf(node)
                if leaf is not None:
                    done.append(leaf)
                    continue
                stack.append((node, len(done)))
                for child in reversed(self._children(node)):
                    stack.append((child, -1))
                continue
            args = done[mark:]
            del done[mark:]
            if isinstance(node, ast.Name) and node.id in self.lets:  # a let done meanwhile by a sibling
                done.append(self.lets[node.id])
                continue
            done.append(self._combine(node, args))
        return done[0]


class _Gen(LetWalker):
    """Straight-line code for a list of expressions: every operation is one assignment to a
    temporary, emitted in a post-order walk with an explicit stack. Neither the walk nor the
    generated code nests, so a sum of 10,000 terms or a chain of 10,000 lets compiles (Python's
    parser limits nested parentheses; its stack limits recursion). A let is emitted once, before
    its first use."""

    def __init__(self, symbols: Symbols):
        self.sym = symbols
        self.lines: list[str] = []
        self.lets: dict[str, str] = {}  # let name -> the temporary holding its value

    def _temp(self, code: str) -> str:
        name = f"_t{len(self.lines)}"
        self.lines.append(f"    {name} = {code}")
        return name

    def _leaf(self, e: ast.Expr) -> Optional[str]:
        if isinstance(e, ast.Number):
            return _literal(e.value)
        if isinstance(e, ast.Infinity):
            return "_INF"
        if isinstance(e, ast.Name):
            n = e.id
            if n in self.sym.consts:
                return _literal(self.sym.consts[n])
            if n in BUILTIN_CONSTANTS:
                return repr(BUILTIN_CONSTANTS[n])
            if n in self.sym.states:
                return f"S[{self.sym.states[n]}]"
            if n in self.sym.actions:
                return f"A[{self.sym.actions[n]}]"
            if n in self.lets:
                return self.lets[n]
            if n not in self.sym.lets:
                raise KeyError(n)
            return None  # a let not emitted yet: its body first
        if isinstance(e, ast.BoolLiteral):
            return repr(e.value)
        return None

    def _combine(self, e: ast.Expr, args: list[str]) -> str:
        if isinstance(e, ast.Name):
            self.lets[e.id] = args[0]
            return args[0]
        if isinstance(e, ast.Unary):
            return self._temp(f"-{args[0]}")
        if isinstance(e, ast.Binary):
            if e.op == "^":
                return self._temp(f"_F.pow({args[0]}, {args[1]})")
            return self._temp(f"{args[0]} {e.op} {args[1]}")
        if isinstance(e, ast.Compare):
            return self._temp(f"_F.{COMPARE_NAMES[e.op]}({args[0]}, {args[1]})")
        if isinstance(e, ast.Logic):
            if e.op == "implies":
                return self._temp(f"_F.or_(_F.not_({args[0]}), {args[1]})")
            return self._temp(f"_F.{e.op}_({args[0]}, {args[1]})")
        if isinstance(e, ast.Not):
            return self._temp(f"_F.not_({args[0]})")
        if isinstance(e, ast.Conditional):
            return self._temp(f"_F.where({args[0]}, {args[1]}, {args[2]})")
        return self._temp(f"_F.{e.func}({', '.join(args)})")

    def expr(self, root: ast.Expr) -> str:
        """Emit ``root``; returns the temporary (or literal) that holds its value."""
        return self.walk(root)


def _literal(value: float) -> str:
    """A float as Python source; ``1e400`` overflows to inf, which ``repr`` would print as a name."""
    v = float(value)
    if math.isfinite(v):
        return repr(v)
    if math.isnan(v):
        return "_NAN"
    return "_INF" if v > 0 else "(-_INF)"


def compile_function(exprs: Sequence[ast.Expr], symbols: Symbols, backend: SimpleNamespace = NUMPY) -> Callable:
    """Compile ``exprs`` to ``f(S, A) -> tuple`` for ``backend`` (numpy, casadi or interval)."""
    gen = _Gen(symbols)
    bodies = [gen.expr(e) for e in exprs]
    lines = ["def _compiled(S, A):", *gen.lines, f"    return ({', '.join(bodies)}{',' if len(bodies) == 1 else ''})"]
    source = "\n".join(lines)
    namespace = {"_F": backend, "_INF": math.inf, "_NAN": math.nan}
    exec(compile(source, "<asap expression>", "exec"), namespace)  # noqa: S102 - our own generated code
    fn = namespace["_compiled"]
    fn.source = source  # type: ignore[attr-defined]
    return fn


def compile_batched(exprs: Sequence[ast.Expr], symbols: Symbols) -> Callable[[np.ndarray, Optional[np.ndarray]], np.ndarray]:
    """``f(states [..., n], actions [..., m] or None) -> [..., len(exprs)]`` with numpy."""
    fn = compile_function(exprs, symbols, NUMPY)
    k = len(exprs)

    def batched(states: np.ndarray, actions: Optional[np.ndarray] = None) -> np.ndarray:
        S = np.moveaxis(states, -1, 0)
        A = np.moveaxis(actions, -1, 0) if actions is not None else ()
        out = fn(S, A)
        shape = states.shape[:-1]
        return np.stack([np.broadcast_to(np.asarray(o, dtype=float), shape) for o in out], axis=-1) if k else np.zeros(shape + (0,))

    batched.source = fn.source  # type: ignore[attr-defined]
    return batched


def compile_scalar(expr: ast.Expr, symbols: Symbols) -> Callable[[np.ndarray], np.ndarray]:
    """``f(states [..., n]) -> [...]``: one expression over states (formulas, regions)."""
    fn = compile_function([expr], symbols, NUMPY)

    def scalar(states: np.ndarray) -> np.ndarray:
        out = fn(np.moveaxis(states, -1, 0), ())[0]
        return np.broadcast_to(np.asarray(out, dtype=float), states.shape[:-1])

    return scalar


def interval_range(expr: ast.Expr, symbols: Symbols, state_box: Sequence[tuple[float, float]],
                   action_box: Sequence[tuple[float, float]] = ()) -> intervals.Interval:
    """A sound enclosure of ``expr`` over the box of states (and actions)."""
    fn = compile_function([expr], symbols, INTERVAL)
    S = [intervals.Interval(float(lo), float(hi)) for lo, hi in state_box]
    A = [intervals.Interval(float(lo), float(hi)) for lo, hi in action_box]
    try:
        out = fn(S, A)[0]
    except (ZeroDivisionError, OverflowError, ValueError):
        return intervals.Interval(-math.inf, math.inf)
    return intervals.Interval.of(out)


def evaluate_constant(expr: ast.Expr, consts: Mapping[str, float]) -> float:
    """Fold a constant expression (no states, actions or lets) to a float."""
    fn = compile_function([expr], Symbols(consts, {}, {}, {}), _MATH)
    try:
        return float(fn((), ())[0])
    except ZeroDivisionError:  # 1/0: not a real number; the checker says so
        return math.nan
    except OverflowError:  # 10^400 in a product: beyond a float; the checker says so
        return math.inf


def _safe_math(f):
    """``f`` giving NaN outside its domain (log(-1)) and infinity past a float's range (exp(1000),
    2^99999), as numpy would, so that the checker can say which of the two happened."""
    def g(*args):
        try:
            return f(*args)
        except OverflowError:
            return math.inf
        except (ValueError, ZeroDivisionError):
            return math.nan
    return g


#: Conditionals on Python floats (constant folding, the batch-1 monitor).
_PYTHON_TESTS = _tests(lambda a, b: a and b, lambda a, b: a or b, lambda a: not a, lambda c, a, b: a if c else b)

_MATH = SimpleNamespace(
    **{k: _safe_math(getattr(math, k)) for k in ("sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh", "exp", "log", "sqrt")},
    abs=abs, min=min, max=max, norm=lambda *xs: math.sqrt(sum(x * x for x in xs)),
    pow=_safe_math(lambda a, b: float(a) ** float(b) if not (a < 0 and not float(b).is_integer()) else math.nan),
    clip=_clipped(min, max), **_PYTHON_TESTS,
)


# Python floats for one state at a time (the batch-1 monitor): math's functions, which *raise*
# where numpy would give NaN or inf, so that such a case can be computed by numpy instead.
SCALAR = SimpleNamespace(
    **{k: getattr(math, k) for k in ("sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh",
                                      "exp", "log", "sqrt")},
    abs=abs, min=min, max=max, norm=lambda *xs: math.sqrt(sum(x * x for x in xs)), pow=math.pow,
    clip=_clipped(min, max), **_PYTHON_TESTS,
)


class ScalarForm:
    """An atom for one state of Python floats: ``row -> (robustness, satisfied)``, compiled on
    first use from ``build()`` (a function of ``row``). Where Python's math raises (a domain
    error, an overflow, a division by zero), ``fallback(row)`` computes it with numpy instead,
    so that the value is the batched evaluator's."""

    __slots__ = ("_build", "_fn", "_fallback", "_build_rho")

    def __init__(self, build: Callable[[], Callable], fallback: Callable,
                 build_rho: Optional[Callable[[], Callable]] = None):
        self._build, self._fn, self._fallback, self._build_rho = build, None, fallback, build_rho

    def compiled(self) -> Callable:
        """The compiled function itself (no fallback): for callers that handle the failures."""
        if self._fn is None:
            self._fn = self._build()
        return self._fn

    def compiled_rho(self) -> Callable:
        """``row -> robustness`` alone, compiled (no fallback; no Boolean computed)."""
        if self._build_rho is None:
            fn = self.compiled()
            return lambda row: fn(row)[0]
        return self._build_rho()

    def __call__(self, row):
        fn = self._fn
        if fn is None:
            fn = self._fn = self._build()
        try:
            out = fn(row)
        except (ArithmeticError, ValueError):
            return self._fallback(row)
        if out[0] != out[0]:  # NaN (inf - inf): numpy's min/max treat it differently from Python's
            return self._fallback(row)
        return out


def scalar_comparison(left: ast.Expr, right: ast.Expr, op: str, symbols: Symbols, fallback: Callable) -> ScalarForm:
    """The scalar form of ``left op right`` (robustness ``right - left`` for < and <=)."""
    import operator

    compare = {"<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge}[op]
    less = op in ("<", "<=")

    def build():
        fn = compile_function([left, right], symbols, SCALAR)

        def atom(row, _fn=fn, _cmp=compare, _less=less):
            a, b = _fn(row, ())
            return (b - a if _less else a - b), _cmp(a, b)
        return atom

    def build_rho():  # the margin as the batched atom computes it: one expression, one call
        margin = ast.Binary("-", right, left, left.span) if less else ast.Binary("-", left, right, left.span)
        fn = compile_function([margin], symbols, SCALAR)
        return lambda row, _fn=fn: _fn(row, ())[0]
    return ScalarForm(build, fallback, build_rho)


def nodes_in(e: ast.Expr) -> Iterable[ast.Expr]:
    """Every node of an expression (formulas included), in source order (an explicit stack:
    a chain of 10,000 terms is 10,000 deep)."""
    stack = [e]
    while stack:
        node = stack.pop()
        yield node
        stack.extend(reversed(_children(node)))


def names_in(e: ast.Expr) -> Iterable[ast.Name]:
    """Every Name node in an expression (formulas included), in source order."""
    return (n for n in nodes_in(e) if isinstance(n, ast.Name))


def _children(e) -> tuple:
    if isinstance(e, (ast.Unary, ast.Not)):
        return (e.arg,)
    if isinstance(e, ast.Temporal):
        return (e.arg,)
    if isinstance(e, (ast.Binary, ast.Compare, ast.Logic, ast.Temporal2)):
        return (e.left, e.right)
    if isinstance(e, ast.Call):
        return e.args
    if isinstance(e, ast.Conditional):
        return (e.test, e.then_, e.else_)
    return ()


def degree(e: ast.Expr, symbols: Symbols) -> float:
    """Polynomial degree in states and actions (constants 0); ``inf`` when not polynomial.

    Used to check that ``integrator exact`` is given linear (affine) dynamics. A post-order walk
    with an explicit stack (lets followed, each once)."""
    let_degree: dict[str, float] = {}
    done: list[float] = []
    stack: list[tuple[ast.Expr, bool]] = [(e, False)]
    while stack:
        node, expanded = stack.pop()
        if isinstance(node, ast.Name) and node.id in symbols.lets and node.id not in symbols.states:
            if node.id in let_degree:
                done.append(let_degree[node.id])
            elif expanded:
                let_degree[node.id] = done[-1]
            else:
                stack.append((node, True))
                stack.append((symbols.lets[node.id], False))
            continue
        kids = _children(node) if isinstance(node, _NUMERIC_PARENTS) else ()
        if not expanded and kids:
            stack.append((node, True))
            stack.extend((k, False) for k in reversed(kids))
            continue
        args = [done.pop() for _ in kids][::-1]
        done.append(_degree_of(node, args, symbols))
    return done[0]


#: The nodes with children that may stand in a numeric expression (a conditional's test included).
_NUMERIC_PARENTS = (ast.Unary, ast.Binary, ast.Call, ast.Conditional, ast.Compare, ast.Logic, ast.Not)


def _degree_of(e: ast.Expr, args: list[float], symbols: Symbols) -> float:
    """The degree of ``e`` from its children's degrees ``args``."""
    if isinstance(e, (ast.Number, ast.Infinity)):
        return 0
    if isinstance(e, ast.Name):
        return 1 if (e.id in symbols.states or e.id in symbols.actions) else 0
    if isinstance(e, ast.Unary):
        return args[0]
    if isinstance(e, ast.Binary):
        a, b = args
        if e.op in "+-":
            return max(a, b)
        if e.op == "*":
            return a + b
        if e.op == "/":
            return a if b == 0 else math.inf
        if e.op == "^":
            if b != 0:
                return math.inf
            if a == 0:
                return 0
            p = evaluate_constant(e.right, symbols.consts)
            return a * p if p >= 0 and float(p).is_integer() else math.inf
    if isinstance(e, (ast.Call, ast.Conditional, ast.Compare, ast.Logic, ast.Not, ast.BoolLiteral)):
        return 0 if all(a == 0 for a in args) else math.inf  # clip and if are piecewise: not polynomial
    return math.inf
