"""Interval arithmetic over boxes: sound enclosures of an expression's range.

Used to bound robustness over the state space (the ``r_sat auto`` of the theorem) and by lint
rules. :class:`Interval` supports the operators the language has; :data:`FUNCTIONS` the
functions. Enclosures are sound (never too narrow, and the whole line where an operation may give NaN)
and exact for monotone pieces.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Union

Number = Union[int, float]


@dataclass(frozen=True)
class Interval:
    lo: float
    hi: float

    @staticmethod
    def of(x: Union["Interval", Number]) -> "Interval":
        return x if isinstance(x, Interval) else Interval(float(x), float(x))

    @property
    def width(self) -> float:
        return self.hi - self.lo

    def contains(self, x: float) -> bool:
        return self.lo <= x <= self.hi

    def __add__(self, o):
        o = Interval.of(o)
        return Interval(self.lo + o.lo, self.hi + o.hi)

    __radd__ = __add__

    def __neg__(self):
        return Interval(-self.hi, -self.lo)

    def __pos__(self):
        return self

    def __sub__(self, o):
        o = Interval.of(o)
        return Interval(self.lo - o.hi, self.hi - o.lo)

    def __rsub__(self, o):
        return Interval.of(o) - self

    def __mul__(self, o):
        o = Interval.of(o)
        products = [_mul(a, b) for a in (self.lo, self.hi) for b in (o.lo, o.hi)]
        return Interval(min(products), max(products))

    __rmul__ = __mul__

    def __truediv__(self, o):
        o = Interval.of(o)
        if o.lo <= 0.0 <= o.hi:  # the divisor may be zero: no finite enclosure
            return Interval(-math.inf, math.inf)
        # The quotients of the corners, not self * (1 / o): 1 / 2e-309 overflows where 0.25 / 2e-309
        # does not. inf / inf has no value: then the reciprocal's enclosure (0 * inf is 0 there).
        q = [a / b for a in (self.lo, self.hi) for b in (o.lo, o.hi)]
        if any(math.isnan(v) for v in q):
            return self * Interval(1.0 / o.hi, 1.0 / o.lo)
        return Interval(min(q), max(q))

    def __rtruediv__(self, o):
        return Interval.of(o) / self

    def __pow__(self, o):
        o = Interval.of(o)
        if o.lo == o.hi and float(o.lo).is_integer():
            n = int(o.lo)
            if n == 0:
                return Interval(1.0, 1.0)
            if n < 0:
                return Interval(1.0, 1.0) / (self ** Interval(-n, -n))
            p = lambda v: _power(v, n)  # noqa: E731
            if n % 2 == 1:
                return Interval(p(self.lo), p(self.hi))
            if self.lo >= 0:
                return Interval(p(self.lo), p(self.hi))
            if self.hi <= 0:
                return Interval(p(self.hi), p(self.lo))
            return Interval(0.0, max(p(self.lo), p(self.hi)))
        # Real exponent: defined for a non-negative base only; exp(o * log(self)). A negative base
        # gives NaN (or, at whole exponents, a real of either sign): nothing narrower is sound.
        if self.lo < 0:  # NaN for some base: no enclosure (see asap_dsl.domains)
            return Interval(-math.inf, math.inf)
        return exp(o * log(self))

    def __rpow__(self, o):
        return Interval.of(o) ** self


# The enclosure where an operation leaves its domain for part of its argument: its value there is
# NaN, which no narrower interval encloses. (asap_dsl.domains reports where this happens.)
_UNKNOWN = Interval(-math.inf, math.inf)


def _power(v: float, n: int) -> float:
    """``v ** n`` for a whole ``n >= 1``, saturating to ±inf instead of raising OverflowError."""
    try:
        return v ** n
    except OverflowError:
        return math.inf if v > 0 or n % 2 == 0 else -math.inf


def _mul(a: float, b: float) -> float:
    # 0 * inf is 0 for enclosures (a zero factor is exactly zero).
    if a == 0.0 or b == 0.0:
        return 0.0
    return a * b


def _monotone(f, x: Interval, increasing: bool = True) -> Interval:
    a, b = f(x.lo), f(x.hi)
    return Interval(a, b) if increasing else Interval(b, a)


def _safe(f, v: float, default: float) -> float:
    try:
        return f(v)
    except (ValueError, OverflowError):
        return default


def exp(x) -> Interval:
    x = Interval.of(x)
    return Interval(_safe(math.exp, x.lo, math.inf), _safe(math.exp, x.hi, math.inf))


def log(x) -> Interval:
    x = Interval.of(x)
    if x.lo < 0:  # NaN for part of the argument
        return _UNKNOWN
    lo = -math.inf if x.lo <= 0 else math.log(x.lo)
    hi = -math.inf if x.hi <= 0 else (math.inf if math.isinf(x.hi) else math.log(x.hi))
    return Interval(lo, hi)


def sqrt(x) -> Interval:
    x = Interval.of(x)
    if x.lo < 0:  # NaN for part of the argument
        return _UNKNOWN
    return Interval(math.sqrt(max(x.lo, 0.0)), math.sqrt(max(x.hi, 0.0)) if not math.isinf(x.hi) else math.inf)


def _periodic(x: Interval, f, peak_phase: float, trough_phase: float) -> Interval:
    """Range of sin/cos over x: endpoints plus any peak/trough inside."""
    if x.width >= 2 * math.pi or math.isinf(x.width):
        return Interval(-1.0, 1.0)
    vals = [f(x.lo), f(x.hi)]
    lo, hi = min(vals), max(vals)
    k = math.ceil((x.lo - peak_phase) / (2 * math.pi))
    if peak_phase + 2 * math.pi * k <= x.hi:
        hi = 1.0
    k = math.ceil((x.lo - trough_phase) / (2 * math.pi))
    if trough_phase + 2 * math.pi * k <= x.hi:
        lo = -1.0
    return Interval(lo, hi)


def sin(x) -> Interval:
    return _periodic(Interval.of(x), math.sin, math.pi / 2, -math.pi / 2)


def cos(x) -> Interval:
    return _periodic(Interval.of(x), math.cos, 0.0, math.pi)


def tan(x) -> Interval:
    x = Interval.of(x)
    k = math.floor((x.lo + math.pi / 2) / math.pi)
    if x.width >= math.pi or math.floor((x.hi + math.pi / 2) / math.pi) != k:
        return Interval(-math.inf, math.inf)
    return _monotone(math.tan, x)


def asin(x) -> Interval:
    x = Interval.of(x)
    if x.lo < -1 or x.hi > 1:  # NaN for part of the argument
        return _UNKNOWN
    return Interval(math.asin(max(-1.0, min(1.0, x.lo))), math.asin(max(-1.0, min(1.0, x.hi))))


def acos(x) -> Interval:
    x = Interval.of(x)
    if x.lo < -1 or x.hi > 1:
        return _UNKNOWN
    return Interval(math.acos(max(-1.0, min(1.0, x.hi))), math.acos(max(-1.0, min(1.0, x.lo))))


def atan(x) -> Interval:
    return _monotone(math.atan, Interval.of(x))


def atan2(y, x) -> Interval:
    y, x = Interval.of(y), Interval.of(x)
    if x.lo > 0:  # right half-plane: atan(y/x), continuous
        corners = [math.atan2(a, b) for a in (y.lo, y.hi) for b in (x.lo, x.hi)]
        return Interval(min(corners), max(corners))
    return Interval(-math.pi, math.pi)


def sinh(x) -> Interval:
    return _monotone(lambda v: _safe(math.sinh, v, math.copysign(math.inf, v)), Interval.of(x))


def cosh(x) -> Interval:
    x = Interval.of(x)
    c = lambda v: _safe(math.cosh, v, math.inf)  # noqa: E731
    if x.lo >= 0:
        return Interval(c(x.lo), c(x.hi))
    if x.hi <= 0:
        return Interval(c(x.hi), c(x.lo))
    return Interval(1.0, max(c(x.lo), c(x.hi)))


def tanh(x) -> Interval:
    return _monotone(math.tanh, Interval.of(x))


def abs_(x) -> Interval:
    x = Interval.of(x)
    if x.lo >= 0:
        return x
    if x.hi <= 0:
        return -x
    return Interval(0.0, max(-x.lo, x.hi))


def min_(*xs) -> Interval:
    xs = [Interval.of(x) for x in xs]
    return Interval(min(x.lo for x in xs), min(x.hi for x in xs))


def max_(*xs) -> Interval:
    xs = [Interval.of(x) for x in xs]
    return Interval(max(x.lo for x in xs), max(x.hi for x in xs))


def norm(*xs) -> Interval:
    total = Interval(0.0, 0.0)
    for x in xs:
        total = total + Interval.of(x) ** 2
    return sqrt(total)


def clip(x, lo, hi) -> Interval:
    """``min(max(x, lo), hi)``, as every evaluator computes it."""
    return min_(max_(x, lo), hi)


FUNCTIONS = {
    "sin": sin, "cos": cos, "tan": tan, "asin": asin, "acos": acos, "atan": atan, "atan2": atan2,
    "sinh": sinh, "cosh": cosh, "tanh": tanh, "exp": exp, "log": log, "sqrt": sqrt,
    "abs": abs_, "min": min_, "max": max_, "norm": norm, "clip": clip,
}

# ---------------------------------------------------------------- tests of a conditional
# A test over boxes is True (for every point), False (for none) or None (undecided: for some).
# NaN is outside every comparison (False), as in numpy: an enclosure that may hold NaN is the
# whole line, over which no comparison is decided.
Truth = Optional[bool]


def _order(a, b, strict: bool) -> Truth:
    """``a < b`` (``strict``) or ``a <= b`` over the boxes."""
    a, b = Interval.of(a), Interval.of(b)
    if any(math.isnan(v) for v in (a.lo, a.hi, b.lo, b.hi)):
        return None
    if (a.hi < b.lo) if strict else (a.hi <= b.lo):
        return True
    if (a.lo >= b.hi) if strict else (a.lo > b.hi):
        return False
    return None


def _equal(a, b) -> Truth:
    a, b = Interval.of(a), Interval.of(b)
    if a.lo == a.hi == b.lo == b.hi and math.isfinite(a.lo):
        return True
    if a.hi < b.lo or b.hi < a.lo:
        return False
    return None


def and_(a: Truth, b: Truth) -> Truth:
    if a is False or b is False:
        return False
    return True if (a is True and b is True) else None


def or_(a: Truth, b: Truth) -> Truth:
    if a is True or b is True:
        return True
    return False if (a is False and b is False) else None


def not_(a: Truth) -> Truth:
    return None if a is None else not a


def where(test: Truth, a, b) -> Interval:
    """``if test then a else b``: the branch the test decides, else the hull of both."""
    if test is True:
        return Interval.of(a)
    if test is False:
        return Interval.of(b)
    a, b = Interval.of(a), Interval.of(b)
    return Interval(min(a.lo, b.lo), max(a.hi, b.hi))


TESTS = {
    "lt": lambda a, b: _order(a, b, True), "le": lambda a, b: _order(a, b, False),
    "gt": lambda a, b: _order(b, a, True), "ge": lambda a, b: _order(b, a, False),
    "eq": _equal, "ne": lambda a, b: not_(_equal(a, b)),
    "and_": and_, "or_": or_, "not_": not_, "where": where,
}
