"""Where an expression may leave the domain of an operation: interval analysis per node.

``sqrt`` of a negative number, ``log`` of zero or less, ``asin``/``acos`` beyond ±1, a division
by zero and a negative base to a fractional power give NaN or infinity at run time. Over the box
of states (and actions) every node gets a sound enclosure (:mod:`asap_dsl.intervals`); an
operation whose argument's enclosure lies wholly outside its domain *surely* fails (every
state in the box does), one whose enclosure only overlaps the outside *may* fail.

Only the first failing operation along a path is reported: what is computed from a NaN is NaN
for the same reason. The walk uses an explicit stack, since expression depth is the user's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

from . import ast, intervals
from .diagnostics import Span
from .expr import BUILTIN_CONSTANTS, COMPARE_NAMES, LetWalker, Symbols
from .intervals import Interval

_UNKNOWN = Interval(-math.inf, math.inf)


@dataclass(frozen=True)
class DomainIssue:
    """One operation that may (``surely=False``) or must leave its domain over the box."""

    span: Span
    message: str
    surely: bool
    hint: Optional[str] = None  # when the checker's general advice does not fit


def _show(iv: Interval) -> str:
    return f"[{iv.lo:.6g}, {iv.hi:.6g}]"


def _check_call(func: str, args: list[Interval]) -> Optional[tuple[str, bool]]:
    """(message, surely) when ``func`` of these enclosures leaves its domain."""
    if func in ("sqrt", "log"):
        (x,) = args
        strict = func == "log"  # log(0) is -inf: not finite either
        bad_hi = x.hi <= 0 if strict else x.hi < 0
        bad_lo = x.lo <= 0 if strict else x.lo < 0
        if bad_lo:
            want = "positive" if strict else "zero or more"
            how = "is never" if bad_hi else "may not be"
            return f"the argument of {func} ranges over {_show(x)} and {how} {want}", bad_hi
    if func in ("asin", "acos"):
        (x,) = args
        if x.lo < -1 or x.hi > 1:
            never = x.hi < -1 or x.lo > 1
            return (f"the argument of {func} ranges over {_show(x)} and {'is never' if never else 'may not be'} "
                    "within [-1, 1]", never)
    return None


def _check_binary(op: str, a: Interval, b: Interval, exponent: Optional[float]) -> Optional[tuple[str, bool]]:
    if op == "/" and b.lo <= 0 <= b.hi:
        surely = b.lo == b.hi == 0
        return (f"the divisor ranges over {_show(b)} and {'is always' if surely else 'may be'} zero", surely)
    if op == "^":
        whole = exponent is not None and float(exponent).is_integer()
        if a.lo < 0 and not whole:
            surely = a.hi < 0 and exponent is not None
            what = f"the fractional power {exponent:g}" if exponent is not None else "a varying power"
            return (f"the base ranges over {_show(a)} and {'is always' if surely else 'may be'} negative, "
                    f"raised to {what}", surely)
        if a.lo <= 0 <= a.hi and b.lo < 0:
            surely = a.lo == a.hi == 0 and b.hi < 0
            return (f"the base ranges over {_show(a)} and {'is always' if surely else 'may be'} zero, "
                    "raised to a negative power (a division by zero)", surely)
    return None


def domain_issues(exprs: Sequence[ast.Expr], symbols: Symbols, state_box: Sequence[tuple[float, float]],
                  action_box: Sequence[tuple[float, float]] = ()) -> list[DomainIssue]:
    """The operations of ``exprs`` (lets they use included) that may leave their domain."""
    return DomainChecker(symbols, state_box, action_box).check(exprs)


class DomainChecker:
    """Checks expressions one call at a time over one box, remembering the lets already walked
    (each let is walked once however many expressions use it: linear in the spec)."""

    def __init__(self, symbols: Symbols, state_box: Sequence[tuple[float, float]],
                 action_box: Sequence[tuple[float, float]] = ()):
        self._walker = _Walker(symbols, state_box, action_box)

    def check(self, exprs: Sequence[ast.Expr]) -> list[DomainIssue]:
        """The issues first met in ``exprs`` (an issue inside a let is reported once, on first use)."""
        start = len(self._walker.issues)
        for e in exprs:
            self._walker.value(e)
        return self._walker.issues[start:]


class _Walker(LetWalker):
    def __init__(self, symbols: Symbols, state_box, action_box):
        self.sym = symbols
        self.states = [Interval(float(lo), float(hi)) for lo, hi in state_box]
        self.actions = [Interval(float(lo), float(hi)) for lo, hi in action_box]
        self.lets: dict[str, tuple[Interval, bool]] = {}  # let -> (enclosure, already failing)
        self.issues: list[DomainIssue] = []
        self._seen: set[tuple[int, int, int, int]] = set()

    def _leaf(self, e) -> Optional[tuple[Interval, bool]]:
        if isinstance(e, ast.Number):
            return Interval.of(e.value), False
        if isinstance(e, ast.Infinity):
            return Interval(math.inf, math.inf), False
        if isinstance(e, ast.Name):
            n, s = e.id, self.sym
            if n in s.consts:
                return Interval.of(s.consts[n]), False
            if n in BUILTIN_CONSTANTS:
                return Interval.of(BUILTIN_CONSTANTS[n]), False
            if n in s.states:
                return self.states[s.states[n]], False
            if n in s.actions:
                i = s.actions[n]
                return (self.actions[i] if i < len(self.actions) else _UNKNOWN), False
            if n in self.lets:
                return self.lets[n]
            if n not in s.lets:
                return _UNKNOWN, False
        if isinstance(e, ast.BoolLiteral):
            return e.value, False
        return None

    def _not_arithmetic(self, e) -> list:
        return []  # no enclosure: _combine makes it unknown

    def _report(self, span: Span, found: tuple) -> None:  # (message, surely[, hint])
        key = (span.line, span.column, span.end_line, span.end_column)
        if key not in self._seen:
            self._seen.add(key)
            self.issues.append(DomainIssue(span, *found))

    def _combine(self, e, args: list[tuple[Interval, bool]]) -> tuple[Interval, bool]:
        failing = any(f for _, f in args)
        vals = [v for v, _ in args]
        if isinstance(e, ast.Name):  # a let: its body's value
            self.lets[e.id] = args[0]
            return args[0]
        found = None
        overflow = False
        try:
            if isinstance(e, ast.Unary):
                out = -vals[0]
            elif isinstance(e, ast.Binary):
                a, b = vals
                if not failing:
                    exponent = b.lo if e.op == "^" and b.lo == b.hi else None
                    found = _check_binary(e.op, a, b, exponent)
                out = {"+": a.__add__, "-": a.__sub__, "*": a.__mul__, "/": a.__truediv__, "^": a.__pow__}[e.op](b)
            elif isinstance(e, ast.Call):
                if not failing:
                    found = _check_call(e.func, vals)
                out = intervals.FUNCTIONS[e.func](*vals)
            elif isinstance(e, (ast.Compare, ast.Logic, ast.Not)):
                # A test: True, False or undecided (None) over the box. Both branches of a
                # conditional are checked over the whole box, whichever the test picks.
                return _test(e, vals), failing
            elif isinstance(e, ast.Conditional):
                out = intervals.where(*vals)
            else:
                out = _UNKNOWN
        except OverflowError:
            out, overflow = _UNKNOWN, True
        except (ZeroDivisionError, ValueError):
            out = _UNKNOWN
        if found is None and not failing and all(_finite(v) for v in vals) and (
                overflow or math.isinf(out.lo) or math.isinf(out.hi)):
            # Finite numbers in, an infinity out: the operation overflows, for every state when its
            # operands are constants, for some when they range (exp(1000 * x)).
            if all(_finite_point(v) for v in vals):
                found = ("this operation overflows: its value is beyond the largest number a float holds "
                         "(±1.8e308)", True)
            else:
                found = ("this operation may overflow: over the state space its value reaches beyond the "
                         "largest number a float holds (±1.8e308)", False,
                         "narrow the state space, or bound what grows (for example exp(min(x, 700)))")
        if found is not None:
            self._report(e.span, found)
            return _UNKNOWN, True
        if math.isnan(out.lo) or math.isnan(out.hi):  # inf - inf, inf / inf, ...
            if not failing:
                point = all(v.lo == v.hi for v in vals)
                self._report(e.span, ("this operation on infinite values (inf - inf, inf / inf, ...) "
                                      f"{'is' if point else 'may be'} not a number", point))
                return _UNKNOWN, True
            out = _UNKNOWN
        return out, failing

    def value(self, root) -> tuple[Interval, bool]:
        return self.walk(root)


def _finite(v) -> bool:
    return isinstance(v, Interval) and math.isfinite(v.lo) and math.isfinite(v.hi)


def _finite_point(v) -> bool:
    return isinstance(v, Interval) and v.lo == v.hi and math.isfinite(v.lo)


def _test(e, vals: list) -> intervals.Truth:
    """The truth over the box of a conditional's test node from its operands' values."""
    t = intervals.TESTS
    if isinstance(e, ast.Compare):
        return t[COMPARE_NAMES[e.op]](*vals)
    if isinstance(e, ast.Not):
        return t["not_"](vals[0])
    a, b = vals
    if e.op == "implies":
        return t["or_"](t["not_"](a), b)
    return t[f"{e.op}_"](a, b)


__all__ = ["DomainChecker", "DomainIssue", "domain_issues"]
