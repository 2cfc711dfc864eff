"""Expressions and region measures as numba source, with numpy's operation order.

The expressions come from the expression compiler's own generator (:class:`asap_dsl.expr._Gen`:
straight-line code, one temporary per operation, each let once); only the meaning of its calls
(``_F.sin``, ``_F.pow``, ...) changes: :data:`PRELUDE` defines them for numba on Python floats so
that each computes what numpy computes on arrays:

* ``min``/``max`` are ``np.minimum``/``np.maximum`` (NaN wins; of two equal values the second);
* ``x ^ c`` with a constant ``c`` in 2, 0.5, -1, 1, 0 is numpy's fast path (``x * x``, ``sqrt``,
  ``1 / x``, ``x``, ``1``), any other power is the C library's ``pow``;
* sums of squares (ball regions, distances) are numpy's pairwise summation
  (:func:`pairwise_sum`), which for fewer than 8 terms is the sum from left to right.

What cannot be the same: numpy evaluates ``tan``, ``atan``, ``exp``, ``log``, ``sinh``, ``cosh``,
``tanh``, ``asin``, ``acos``, ``atan2`` and ``pow`` (other exponents) with its own SIMD code on
machines with AVX-512, which differs from the C library in the last bit for a few percent of
arguments; ``sin``, ``cos``, ``sqrt`` and the arithmetic are the same to the bit.
"""

from __future__ import annotations

from typing import Sequence

from .. import ast
from ..diagnostics import Span
from ..expr import Symbols, _Gen, _literal

#: What every generated module starts with: numba, and numpy's min/max as intrinsics.
PRELUDE = '''\
import math

import numpy as np
from llvmlite import ir as llir
from numba import njit, types
from numba.extending import intrinsic

# error_model="numpy": 1 / 0 is inf and 0 / 0 NaN, as in numpy, never an exception.
_JIT = dict(cache=True, error_model="numpy", boundscheck=False, nogil=True)
_INF = math.inf
_NAN = math.nan
_BIG = 4611686018427387904  # 2**62: "no step" in index fields


def _select(strict):
    # np.minimum / np.maximum of two floats as one select (NaN wins; of equal values the
    # second): an intrinsic, because a call to a numba function or a ufunc costs compile time
    # at every use and a conditional expression costs branches.
    @intrinsic
    def pick(typingctx, a, b):
        def codegen(context, builder, signature, args):
            x, y = args
            take_x = builder.or_(builder.fcmp_ordered(strict, x, y), builder.fcmp_unordered("uno", x, x))
            return builder.select(take_x, x, y)
        return types.float64(types.float64, types.float64), codegen
    return pick


_mn = _select("<")
_mx = _select(">")
'''


def mn(a: str, b: str) -> str:
    """``np.minimum(a, b)`` (NaN wins; of equal values the second), as float64."""
    return f"_mn({a}, {b})"


def mx(a: str, b: str) -> str:
    """``np.maximum(a, b)``, as float64."""
    return f"_mx({a}, {b})"


_MATH = {"sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh", "exp", "log", "sqrt"}
#: numpy's fast paths of ``np.power`` with a scalar exponent.
_POWERS = {2.0: "{a} * {a}", 0.5: "math.sqrt({a})", -1.0: "1.0 / {a}", 1.0: "{a}", 0.0: "1.0"}


def _constant(code: str):
    """The value of a literal the generator wrote, or None for a temporary or a state."""
    try:
        return float(code)
    except ValueError:
        return None


class _NumbaGen(_Gen):
    """The expression generator with calls written for numba on floats (numpy's meaning). It
    also knows which temporaries are constants (numpy computes them as Python floats, and a
    constant exponent takes numpy's fast paths)."""

    def __init__(self, symbols: Symbols):
        super().__init__(symbols)
        self.constants: set[str] = set()

    def is_constant(self, code: str) -> bool:
        return _constant(code) is not None or code in ("_INF", "(-_INF)", "_NAN") or code in self.constants

    def _combine(self, e: ast.Expr, args: list[str]) -> str:
        out = self._combine_numba(e, args)
        if not isinstance(e, ast.Name) and all(self.is_constant(a) for a in args):
            self.constants.add(out)
        return out

    def _combine_numba(self, e: ast.Expr, args: list[str]) -> str:
        if isinstance(e, ast.Binary) and e.op == "^":
            return self._power(*args)
        if isinstance(e, ast.Call):
            f = e.func
            if f in _MATH:
                return self._temp(f"math.{f}({', '.join(args)})")
            if f == "abs":
                return self._temp(f"math.fabs({args[0]})")
            if f in ("min", "max"):
                acc = args[0]
                for x in args[1:]:
                    acc = self._temp((mn if f == "min" else mx)(acc, x))
                return acc
            if f == "clip":  # np.minimum(np.maximum(x, lo), hi), as asap_dsl.expr defines it
                return self._temp(mn(self._temp(mx(args[0], args[1])), args[2]))
            if f == "norm":  # np.sqrt(sum(np.square(x) for x in xs)): left to right
                sq = [self._temp(f"{x} * {x}") for x in args]
                acc = sq[0]
                for x in sq[1:]:
                    acc = self._temp(f"{acc} + {x}")
                return self._temp(f"math.sqrt({acc})")
            raise NotCovered(f"the function {f}")
        # A conditional and its test: Python's comparisons and `and`/`or`/`not` on floats are
        # numpy's elementwise ones (NaN compares False); np.where is the choice.
        if isinstance(e, ast.Compare):
            return self._temp(f"{args[0]} {e.op} {args[1]}")
        if isinstance(e, ast.Logic):
            a, b = args
            return self._temp(f"(not {a}) or {b}" if e.op == "implies" else f"{a} {e.op} {b}")
        if isinstance(e, ast.Not):
            return self._temp(f"not {args[0]}")
        if isinstance(e, ast.Conditional):
            return self._temp(f"{args[1]} if {args[0]} else {args[2]}")
        return super()._combine(e, args)

    def _power(self, a: str, b: str) -> str:
        c = _constant(b)
        if c is not None:
            return self._temp(_POWERS[c].format(a=a) if c in _POWERS else f"math.pow({a}, {b})")
        if not self.is_constant(b):  # an exponent over the batch: numpy's general power
            return self._temp(f"math.pow({a}, {b})")
        # A constant computed at run time: numpy's fast paths apply to it (a scalar).
        code = f"math.pow({a}, {b})"
        for value, form in reversed(list(_POWERS.items())):
            code = f"({form.format(a=a)} if {b} == {value!r} else {code})"
        return self._temp(code)


class NotCovered(Exception):
    """The compiled step does not cover this spec (the reason is the message); the numpy path runs it."""


class Body:
    """The lines of one generated function body: expressions through the expression generator
    (states read from the tuple ``S``), and this module's own lines and temporaries beside them."""

    def __init__(self, symbols: Symbols, indent: int = 1):
        self.gen = _NumbaGen(symbols)
        self.indent = indent
        self._own = 0

    @property
    def lines(self) -> list[str]:
        return self.gen.lines

    def expr(self, e: ast.Expr) -> str:
        """Emit ``e``; the temporary or literal holding its value."""
        return self.gen.expr(e)

    def name(self, coord: str) -> str:
        """The value of a state or let by name."""
        return self.expr(ast.Name(coord, Span()))

    def line(self, code: str, extra: int = 0) -> None:
        self.gen.lines.append("    " * (self.indent + extra) + code)

    def temp(self, code: str, prefix: str = "_u") -> str:
        """A new temporary of this module's own, assigned ``code``."""
        self._own += 1
        name = f"{prefix}{self._own}"
        self.line(f"{name} = {code}")
        return name


def number(value: float) -> str:
    """A float as source (``inf`` and NaN as names)."""
    return _literal(value)


def pairwise_sum(body: Body, terms: Sequence[str]) -> str:
    """The sum of ``terms`` in the order of numpy's pairwise summation of a contiguous row
    (``np.sum(x, axis=-1)``): left to right below 8 terms, eight partial sums up to 128,
    halves (rounded to a multiple of 8) above."""
    terms = list(terms)
    n = len(terms)
    if n == 0:
        return "0.0"
    if n < 8:
        acc = terms[0]
        for t in terms[1:]:
            acc = body.temp(f"{acc} + {t}")
        return acc
    if n <= 128:
        r = list(terms[:8])
        i = 8
        while i < n - n % 8:
            r = [body.temp(f"{r[j]} + {terms[i + j]}") for j in range(8)]
            i += 8
        a = body.temp(f"({r[0]} + {r[1]}) + ({r[2]} + {r[3]})")
        b = body.temp(f"({r[4]} + {r[5]}) + ({r[6]} + {r[7]})")
        res = body.temp(f"{a} + {b}")
        for t in terms[i:]:
            res = body.temp(f"{res} + {t}")
        return res
    half = n // 2
    half -= half % 8
    return body.temp(f"{pairwise_sum(body, terms[:half])} + {pairwise_sum(body, terms[half:])}")


def region_values(body: Body, region) -> list[str]:
    """The region's coordinates (states or lets) at the state ``S``."""
    return [body.name(c) for c in region.coords]


def region_atom(body: Body, region) -> tuple[str, str]:
    """(robustness, satisfied as +1.0 / -1.0) of ``in region``, as
    :meth:`asap_dsl.model.RegionModel.robustness` and ``satisfied`` compute them."""
    v = region_values(body, region)
    if region.kind == "ball":
        d = [body.temp(f"{x} - {number(c)}") for x, c in zip(v, region.centre)]
        d2 = pairwise_sum(body, [body.temp(f"{x} * {x}") for x in d])
        rob = body.temp(f"{number(region.radius)} - math.sqrt({d2})")
        sat = body.temp(f"1.0 if {d2} <= {number(region.radius ** 2)} else -1.0")
        return rob, sat
    sides = []
    for x, lo, hi in zip(v, region.low, region.high):
        a, b = body.temp(f"{x} - {number(lo)}"), body.temp(f"{number(hi)} - {x}")
        sides.append(body.temp(mn(a, b)))
    rob = sides[0]
    for s in sides[1:]:  # np.min over the sides: NaN wins, otherwise the smallest
        rob = body.temp(mn(rob, s))
    inside = " and ".join(f"({x} >= {number(lo)} and {x} <= {number(hi)})" for x, lo, hi in zip(v, region.low, region.high))
    sat = body.temp(f"1.0 if ({inside}) else -1.0")
    return rob, sat


def region_distance(body: Body, region) -> str:
    """The Euclidean distance from the region, as :meth:`asap_dsl.model.RegionModel.distance`."""
    v = region_values(body, region)
    if region.kind == "ball":
        d = [body.temp(f"{x} - {number(c)}") for x, c in zip(v, region.centre)]
        d2 = pairwise_sum(body, [body.temp(f"{x} * {x}") for x in d])
        return body.temp(mx("0.0", body.temp(f"math.sqrt({d2}) - {number(region.radius)}")))
    gaps = []
    for x, lo, hi in zip(v, region.low, region.high):
        below, above = body.temp(f"{number(lo)} - {x}"), body.temp(f"{x} - {number(hi)}")
        gaps.append(body.temp(f"{mx(below, '0.0')} + {mx(above, '0.0')}"))
    g2 = pairwise_sum(body, [body.temp(f"{g} * {g}") for g in gaps])
    return body.temp(f"math.sqrt({g2})")


_COMPARE = {"<": "<", "<=": "<=", ">": ">", ">=": ">="}


def comparison_atom(body: Body, margin: ast.Expr, op: str) -> tuple[str, str]:
    """(robustness, satisfied as +1.0 / -1.0) of a comparison ``left op right`` from its margin
    (``right - left`` for < and <=, ``left - right`` for > and >=, as the checker builds it)."""
    if not isinstance(margin, ast.Binary) or margin.op != "-" or op not in _COMPARE:
        raise NotCovered("a comparison atom without its margin and operator")
    less = op in ("<", "<=")
    left, right = (margin.right, margin.left) if less else (margin.left, margin.right)
    a, b = body.expr(left), body.expr(right)
    rob = body.temp(f"{b} - {a}" if less else f"{a} - {b}")
    sat = body.temp(f"1.0 if {a} {op} {b} else -1.0")
    return rob, sat
