"""The checks every part of the checker builds on: names, numbers and times (:class:`Numbers`),
and conditions, formula references and formula declarations (:class:`Conditions`), over the
shared :class:`~asap_dsl.checker_common.CheckState` (see :mod:`asap_dsl.checker`)."""

from __future__ import annotations

import math
from typing import Mapping, Optional

import numpy as np

from . import ast
from .checker_common import (ACTION, CONST, FORMULA, LET, REGION, STATE, _FUTURE_TO_PAST, _MAX_STEPS, CheckState, _a,
                             _Unresolved, dependency_order, each)
from .diagnostics import Span, span_text
from .diagnostics import closest as _closest
from .domains import DomainChecker
from .expr import (BUILTIN_CONSTANTS, FUNCTION_ARITY, Symbols, compile_scalar, evaluate_constant, interval_range,
                   nodes_in, scalar_comparison)
from .formatting import number, plural
from .intervals import Interval
from .limits import LIMITS
from .model import FormulaModel, RegionModel
from .rewards import FLOAT32_MAX
from .stl import ir


class Numbers:
    """Declared names, numeric expressions, constants, ranges and times (in steps)."""

    def __init__(self, state: CheckState):
        self.s = state
        self.d = state.diag
        self._domain_reported: set[Span] = set()  # domain issues already reported (see check_domains)
        self._domains: Optional[tuple[DomainChecker, DomainChecker]] = None  # over states; states and actions

    # ------------------------------------------------------------------ names
    def declare(self, name: str, kind: str, span: Span) -> bool:
        if name in BUILTIN_CONSTANTS:
            self.d.add("E102", f"'{name}' is a built-in constant and cannot be redeclared", span)
            return False
        if name in self.s.kinds:
            prev_kind, prev = self.s.kinds[name]
            self.d.add("E102", f"'{name}' is already declared as a {prev_kind} at line {prev.line}", span)
            return False
        self.s.kinds[name] = (kind, span)
        return True

    def unknown(self, name: str, span: Span, wanted: tuple[str, ...]) -> None:
        kinds = self.s.kinds
        candidates = [n for n, (k, _) in kinds.items() if k in wanted]
        if CONST in wanted:
            candidates += list(BUILTIN_CONSTANTS)
        suggestion = _closest(name, candidates)
        what = " or ".join(dict.fromkeys(wanted)) if wanted else "name"
        msg = f"unknown {what} '{name}'"
        hint = f"did you mean '{suggestion}'?" if suggestion else None
        if name in kinds:
            kind = kinds[name][0]
            self.d.add("E103", f"'{name}' is {_a(kind)}, not a {what}", span, hint=_kind_hint(name, kind, wanted))
            return
        self.d.add("E101", msg, span, hint)

    def not_a_state(self, name: str, span: Span, states: list[str], where: str, code: str, role: str) -> None:
        """Report ``name`` where a state must stand: E101 with the closest state if it is no name
        at all, else ``code`` saying what it is and what ``role`` needs."""
        kind = self.s.kinds.get(name, (None,))[0]
        if kind is None:
            sug = _closest(name, states)
            self.d.add("E101", f"unknown state '{name}' in {where}", span, hint=f"did you mean '{sug}'?" if sug else None)
        else:
            self.d.add(code, f"'{name}' is {_a(kind)}; {role}", span)

    def state_once(self, name: str, span: Span, known: Mapping[str, object], seen: Mapping[str, Span], where: str,
                   code: str, role: str, twice_code: str, twice: str) -> bool:
        """True if ``name`` is a state (a key of ``known``, in declaration order) not given before
        (not a key of ``seen``, which maps a name to where it was given); else it is reported as
        :meth:`not_a_state` does, or with ``twice_code`` as "state 'x' ``twice``" where ``twice``
        says ``{line}`` for the line of the first."""
        if name not in known:
            self.not_a_state(name, span, list(known), where, code, role)
            return False
        if name in seen:
            self.d.add(twice_code, f"state '{name}' " + twice.format(line=seen[name].line), span)
            return False
        return True

    # ------------------------------------------------------------------ numbers
    def number(self, e: ast.Expr, allowed: tuple[str, ...], context: str) -> None:
        """Check that ``e`` is a numeric expression over names of the ``allowed`` kinds."""
        if isinstance(e, (ast.Number, ast.Infinity)):
            return
        if isinstance(e, ast.Duration):  # `substeps = 2s`: a time where only a number can stand
            self.d.add("E117", f"{context} takes a number, not a time", e.span,
                       hint="times (1s, 500ms) are for deadlines, tolerances, windows and episode lengths")
            raise _Unresolved
        if isinstance(e, ast.Name):
            self._name_in_number(e, allowed, context)
            return
        if isinstance(e, ast.Unary):
            self.number(e.arg, allowed, context)
            return
        if isinstance(e, ast.Binary):
            # a + b + ... is left-deep, as long as the user wrote it: walk its spine in a loop and
            # recurse into the right operands only (their nesting is bounded by the parser).
            operands = []
            while isinstance(e, ast.Binary):
                operands.append(e.right)
                e = e.left
            operands.append(e)
            each(lambda side: self.number(side, allowed, context), reversed(operands))
            return
        if isinstance(e, ast.Conditional):
            parts = ((self.test, e.test), (self.number, e.then_), (self.number, e.else_))
            each(lambda part: part[0](part[1], allowed, context), parts)
            return
        if isinstance(e, ast.Call):
            if e.func not in FUNCTION_ARITY:
                sug = _closest(e.func, FUNCTION_ARITY)
                self.d.add("E118", f"unknown function '{e.func}'", e.func_span,
                           hint=f"did you mean '{sug}'?" if sug else "the functions are " + ", ".join(FUNCTION_ARITY))
                raise _Unresolved
            arity = FUNCTION_ARITY[e.func]
            if (arity is not None and len(e.args) != arity) or (arity is None and not e.args):
                want = plural(arity, "argument") if arity else "at least one argument"
                self.d.add("E104", f"{e.func}() takes {want}, given {len(e.args)}", e.span)
                raise _Unresolved
            each(lambda a: self.number(a, allowed, context), e.args)
            return
        self.d.add("E116", f"a condition cannot be used as a number in {context}", e.span)
        raise _Unresolved

    def test(self, e: ast.Expr, allowed: tuple[str, ...], context: str) -> None:
        """Check the test of ``if ... then ... else``: comparisons of numbers over names of the
        ``allowed`` kinds (``==`` and ``!=`` too: a test has no robustness), ``true``/``false``,
        joined by ``and``/``or``/``->``/``not``. An explicit stack: a chain of ``and`` is as long
        as the user wrote it."""
        stack, failed = [e], False
        while stack:
            node = stack.pop()
            if isinstance(node, ast.Logic):
                stack += [node.right, node.left]
            elif isinstance(node, ast.Not):
                stack.append(node.arg)
            elif isinstance(node, ast.Compare):
                try:
                    each(lambda side: self.number(side, allowed, context), (node.left, node.right))
                except _Unresolved:
                    failed = True
            elif not isinstance(node, ast.BoolLiteral):
                failed = True
                if isinstance(node, (ast.InRegion, ast.Temporal, ast.Temporal2)) or (
                        isinstance(node, ast.Name) and self.s.kinds.get(node.id, (None,))[0] == FORMULA):
                    self.d.add("E116", "the test of `if` compares numbers at this step: a region, a formula or a "
                               "temporal operator cannot stand there", node.span,
                               hint="compare the values themselves, for example `if x > 0 then ... else ...`")
                else:
                    self.d.add("E116", "a number cannot be the test of `if`", node.span,
                               hint="compare it, for example `if x > 0 then ... else ...`")
        if failed:
            raise _Unresolved

    def _name_in_number(self, e: ast.Name, allowed: tuple[str, ...], context: str) -> None:
        if e.id in BUILTIN_CONSTANTS:
            return
        s = self.s
        if e.id == "dt" and s.steps_only:
            self.d.add("E114", "`dt` is read here, but the system is a map without `dt`, which counts in steps only",
                       e.span, hint=STEPS_ONLY_HINT)
            raise _Unresolved
        kind = s.kinds.get(e.id, (None,))[0]
        if kind in allowed:
            s.used.add(e.id)
            if kind == CONST and e.id not in s.consts:
                if e.id not in s.const_failed:
                    self.d.add("E101", f"constant '{e.id}' is used before it is declared", e.span,
                               hint="a constant may use the constants declared before it")
                raise _Unresolved
            if kind == LET and e.id not in s.lets:
                raise _Unresolved  # reported where the let is declared
            if kind == LET and ACTION not in allowed and e.id in s.action_lets:
                self.d.add("E103", f"{context} cannot read the let '{e.id}': it reads the action "
                           f"'{s.action_lets[e.id]}', which is known only while stepping", e.span,
                           hint=ACTION_LET_HINT)
                raise _Unresolved
            return
        if kind is not None and kind in (CONST, STATE, ACTION, LET) and kind not in allowed:
            self.d.add("E121" if context == "a constant expression" else "E103",
                       f"{context} cannot read the {kind} '{e.id}'", e.span,
                       hint=_context_hint(context))
            raise _Unresolved
        if kind in (FORMULA, REGION):
            self.d.add("E116", f"'{e.id}' is {_a(kind)}, not a number", e.span,
                       hint=f"write `in {e.id}` for the condition of being in the region" if kind == REGION else None)
            raise _Unresolved
        self.unknown(e.id, e.span, tuple(k for k in allowed))
        raise _Unresolved

    def constant(self, e: ast.Expr, what: str) -> float:
        """Fold a constant expression; report and raise if it reads anything but constants."""
        self.number(e, (CONST,), what if isinstance(e, ast.Duration) else "a constant expression")
        value = evaluate_constant(e, self.s.consts)
        if math.isnan(value):
            self.d.add("E117", f"{what} is not a real number (check divisions, logarithms and roots)", e.span)
            raise _Unresolved
        if math.isinf(value) and not self._reads_infinity(e):
            self.d.add("E117", f"{what} overflows: its value is beyond the largest number a float holds (±1.8e308)",
                       e.span, hint="check the powers, exponentials and products of large numbers")
            raise _Unresolved
        return value

    def _reads_infinity(self, e: ast.Expr) -> bool:
        """Whether a constant expression reads `inf` (itself or through a constant): then an
        infinite value is what was written, not an overflow of finite numbers."""
        return any(isinstance(n, ast.Infinity) or (isinstance(n, ast.Name) and math.isinf(self.s.consts.get(n.id, 0.0)))
                   for n in nodes_in(e))

    def finite_constant(self, e: ast.Expr, what: str) -> float:
        """A constant that a reward computes with: infinity there gives inf - inf = NaN rewards,
        and SB3 stores rewards as float32 (at most about 3.4e38)."""
        value = self.constant(e, what)
        if not abs(value) <= FLOAT32_MAX:
            self.d.add("E117", f"{what} must be a finite number within ±3.4e38 (a float32 reward), not {number(value)}", e.span)
            raise _Unresolved
        return value

    def range_(self, r: ast.Range, what: str) -> tuple[float, float]:
        lo, hi = each(lambda e: self.constant(e, what), (r.lo, r.hi))
        if lo > hi:
            self.d.add("E105", f"{what} [{number(lo)}, {number(hi)}] has its lower bound above its upper bound", r.span,
                       hint=f"write [{number(hi)}, {number(lo)}]")
            raise _Unresolved
        return lo, hi

    # ------------------------------------------------------------------ times
    def steps(self, d: ast.Duration, what: str, allow_inf: bool = False) -> Optional[int]:
        """Convert a duration to whole steps (None for inf); report problems."""
        if d.is_inf:
            if not allow_inf:
                self.d.add("E117", f"{what} cannot be infinite", d.span)
                raise _Unresolved
            return None
        if d.unit == "steps":
            if not float(d.value).is_integer():
                self.d.add("E106", f"{what} {number(d.value)} is not a whole number of steps", d.span,
                           hint="give a whole number of steps, or seconds with a unit such as 1.5s")
                raise _Unresolved
            if d.value > _MAX_STEPS:
                self.d.add("E117", f"{what} {number(d.value)} is more than {_MAX_STEPS:.0e} steps", d.span)
                raise _Unresolved
            return int(d.value)
        seconds = d.value / 1000.0 if d.unit == "ms" else d.value
        dt = self.s.dt
        if dt is None and self.s.steps_only:
            self.d.add("E114", f"{what} is given in seconds, but the system is a map without `dt`, which counts in "
                       "steps only", d.span, hint=STEPS_ONLY_HINT)
            raise _Unresolved
        if dt is None:
            self.d.add("E114", f"{what} is given in seconds, but the system has no valid dt to convert it", d.span)
            raise _Unresolved
        n = seconds / dt
        if not math.isfinite(n) or n > _MAX_STEPS:
            self.d.add("E117", f"{what} {number(d.value)}{d.unit} is more than {_MAX_STEPS:.0e} steps of dt = {number(dt)}", d.span)
            raise _Unresolved
        if abs(n - round(n)) > 1e-9 * max(1.0, abs(n)):
            self.d.add("E106", f"{what} {number(d.value)}{d.unit} is {number(n)} steps of dt = {number(dt)}, not a whole number",
                       d.span, hint=f"use a multiple of {number(dt)}s")
            raise _Unresolved
        return int(round(n))

    def positive_steps(self, d: ast.Duration, what: str) -> int:
        n = self.steps(d, what)
        if n is None or n < 1:
            self.d.add("E117", f"{what} must be at least one step", d.span)
            raise _Unresolved
        return n

    def interval(self, syn: Optional[ast.IntervalSyntax]) -> ir.Interval:
        if syn is None:
            return ir.Interval(0, None)
        lo, hi = each(lambda side: self.steps(*side), ((syn.lo, "the interval's lower bound", False),
                                                        (syn.hi, "the interval's upper bound", True)))
        if hi is not None and lo > hi:
            self.d.add("E105", f"the interval [{lo}, {hi}] (in steps) has its lower bound above its upper bound", syn.span,
                       hint=f"write [{hi}, {lo}]")
            raise _Unresolved
        return ir.Interval(lo, hi)

    # ------------------------------------------------------------------ the system's symbols
    def symbols(self) -> Symbols:
        s = self.s
        return Symbols(dict(s.consts), {v.name: v.index for v in s.states}, {a.name: a.index for a in s.actions},
                       dict(s.lets))

    def state_box(self) -> list[tuple[float, float]]:
        return [(v.low, v.high) for v in self.s.states]

    def check_domains(self, exprs, where: str, actions: bool = False) -> None:
        """E124 where an operation surely leaves its domain over the state space, W209 where it
        may (interval analysis, :mod:`asap_dsl.domains`). Lets are checked once, on their own,
        before any use; an issue is reported once, at its place."""
        if self._domains is None:  # built once the states, actions and lets are known
            symbols, box = self.symbols(), self.state_box()
            self._domains = (DomainChecker(symbols, box),
                             DomainChecker(symbols, box, [(a.low, a.high) for a in self.s.actions]))
        for issue in self._domains[actions].check(exprs):
            if issue.span in self._domain_reported:
                continue
            self._domain_reported.add(issue.span)
            if issue.surely:
                self.d.add("E124", f"{issue.message} (in {where}): the value is NaN or infinite for every state",
                           issue.span, hint="check the expression, or the state space it is evaluated over")
            else:
                self.d.add("W209", f"{issue.message} (in {where}): NaN or infinity there ends an episode as "
                           "`non_finite`", issue.span,
                           hint=issue.hint or "narrow the state space, or guard the argument (for example "
                           "sqrt(abs(x)) or max(x, 1e-9))")


class Conditions:
    """Conditions (formulas) to IR: atoms, references to formulas (built once each, in
    dependency order), causality, and the limits on a formula's depth and size."""

    def __init__(self, state: CheckState, numbers: Numbers):
        self.s, self.n = state, numbers
        self.d = state.diag
        self.lines = state.source.splitlines()
        self._measure_memo: dict = {}  # ir.measure's, shared: formulas are measured once
        self._formula_ir: dict[str, Optional[ir.Formula]] = {}  # None: the formula has errors
        self._formula_stack: list[str] = []
        self._region_decls = {r.name: r for r in state.module.regions}
        self._formula_decls = {f.name: f for f in state.module.formulas}

    def check_formulas(self) -> None:
        # In dependency order, so that a formula's references are built before it and building
        # one never recurses through a chain of formulas (which may be as long as the file).
        decls = {f.name: f for f in self.s.module.formulas if self.s.declared_here(f.name, f.name_span)}
        order, cyclic = dependency_order(
            list(decls), lambda n: (m.id for m in nodes_in(decls[n].body) if isinstance(m, ast.Name) and m.id in decls))
        for name in cyclic:
            self.d.add("E120", f"formula '{name}' is defined in terms of itself", decls[name].name_span)
        ordered = set(order)
        for name in decls:
            if name not in ordered:  # on a cycle, or using one (reported there)
                self._formula_ir[name] = None
        for name in order:
            f = decls[name]
            node = self.formula_ir(f.name)
            if node is not None:
                self.s.formulas[f.name] = FormulaModel(f.name, node, f.span)

    def condition(self, e: ast.Expr, causal_clause: Optional[str] = None) -> ir.Formula:
        """Check a condition and build its IR; ``causal_clause`` names the clause that forbids the future."""
        if isinstance(e, ast.BoolLiteral):
            return ir.Const(e.value)
        if isinstance(e, ast.InRegion):
            return self.region_atom(e)
        if isinstance(e, ast.Compare):
            return self.compare_atom(e)
        if isinstance(e, ast.Name):
            return self.formula_ref(e, causal_clause)
        if isinstance(e, ast.Not):
            return ir.Not(self.condition(e.arg, causal_clause))
        if isinstance(e, ast.Logic):
            # A chain a and b and ... (left-deep, as long as written) is walked in a loop.
            operands = []
            node = e
            while isinstance(node, ast.Logic) and node.op == e.op and e.op != "implies":
                operands.append(node.right)
                node = node.left
            operands.append(node)
            if e.op == "implies":
                operands = [e.right, e.left]
            built = each(lambda side: self.condition(side, causal_clause), reversed(operands))
            if e.op == "implies":
                return ir.Implies(*built)
            return ir.balanced(ir.And if e.op == "and" else ir.Or, built)
        if isinstance(e, (ast.Temporal, ast.Temporal2)):
            return self._temporal(e, causal_clause)
        # A number where a condition is expected.
        self.d.add("E116", "a number cannot be used as a condition", e.span,
                   hint="compare it, for example `x > 0`")
        raise _Unresolved

    def _temporal(self, e, causal_clause: Optional[str]) -> ir.Formula:
        errors = 0
        if causal_clause and e.op in _FUTURE_TO_PAST:
            self.d.add("E107", f"'{causal_clause}' must be causal, but '{e.op}' looks into the future", e.op_span,
                       hint=f"an agent cannot see the future: use the past form '{_FUTURE_TO_PAST[e.op]}'")
            errors += 1
        interval = None
        try:
            interval = self.n.interval(e.interval)
        except _Unresolved:
            errors += 1
        args = (e.arg,) if isinstance(e, ast.Temporal) else (e.left, e.right)
        try:
            built = each(lambda a: self.condition(a, causal_clause), args)
        except _Unresolved:
            errors += 1
        if errors:
            raise _Unresolved
        cls = {"always": ir.Always, "eventually": ir.Eventually, "historically": ir.Historically,
               "once": ir.Once, "until": ir.Until, "since": ir.Since}[e.op]
        return cls(interval, *built)

    def region_atom(self, e: ast.InRegion) -> ir.Formula:
        regions = self.s.regions
        if e.region not in regions:
            if e.region in self._region_decls:
                raise _Unresolved  # the region itself has errors, reported there
            self.n.unknown(e.region, e.name_span, (REGION,))
            raise _Unresolved
        self.s.used.add(e.region)
        region = regions[e.region]
        return ir.Atom(f"in {e.region}", region.robustness, region.satisfied, self.region_bounds(region), e.region,
                       scalar=region.scalar_form(self.n.symbols()))

    def region_bounds(self, region: RegionModel) -> tuple[float, float]:
        # A state's interval is its space (looked up, so that a ball over n states costs O(n));
        # a let's comes from interval analysis over the state box (built once).
        spaces = {s.name: Interval(s.low, s.high) for s in self.s.states}
        box = symbols = None
        coords = []
        for c in region.coords:
            if c in spaces:
                coords.append(spaces[c])
                continue
            if box is None:
                symbols, box = self.n.symbols(), self.n.state_box()
            coords.append(interval_range(ast.Name(c, Span()), symbols, box))
        if region.kind == "ball":
            dist = Interval(0.0, 0.0)
            for iv, c in zip(coords, region.centre):
                dist = dist + (iv - c) ** 2
            lo, hi = math.sqrt(max(dist.lo, 0.0)), math.sqrt(dist.hi) if math.isfinite(dist.hi) else math.inf
            return (region.radius - hi, region.radius - lo)
        # Each side's margin min(v - a, b - v) is a tent over v, highest ((b - a) / 2) at the
        # middle: its range over [v.lo, v.hi] is exact, and the box's is their minimum (exact
        # when the coordinates are states; sound for lets). Never above the smallest half-width.
        lows, highs = [], []
        for iv, a, b in zip(coords, region.low, region.high):
            tent = lambda v, a=a, b=b: min(v - a, b - v)  # noqa: E731
            mid = (a + b) / 2
            lows.append(min(tent(iv.lo), tent(iv.hi)))
            highs.append((b - a) / 2 if iv.lo <= mid <= iv.hi else max(tent(iv.lo), tent(iv.hi)))
        return (min(lows), min(highs))

    def compare_atom(self, e: ast.Compare) -> ir.Formula:
        if e.op in ("==", "!="):
            self.d.add("E115", f"'{e.op}' between real signals cannot be measured by robustness", e.op_span,
                       hint="write `abs(a - b) <= eps`" if e.op == "==" else "write `abs(a - b) > eps`")
            raise _Unresolved
        each(lambda side: self.n.number(side, (CONST, STATE, LET), "a formula"), (e.left, e.right))
        # rho of `a < b` is b - a; of `a > b` is a - b.
        margin = ast.Binary("-", e.right, e.left, e.span) if e.op in ("<", "<=") else ast.Binary("-", e.left, e.right, e.span)
        symbols = self.n.symbols()
        rho = compile_scalar(margin, symbols)
        left, right = compile_scalar(e.left, symbols), compile_scalar(e.right, symbols)
        op = {"<": np.less, "<=": np.less_equal, ">": np.greater, ">=": np.greater_equal}[e.op]

        def satisfied(states, _l=left, _r=right, _op=op):
            return _op(_l(states), _r(states))

        self.n.check_domains([e.left, e.right], "this condition")
        bounds = interval_range(margin, symbols, self.n.state_box())
        def fallback(row, _rho=rho, _sat=satisfied):
            s = np.asarray(row, dtype=np.float64)[None]
            with np.errstate(all="ignore"):
                return float(_rho(s)[0]), bool(_sat(s)[0])

        scalar = scalar_comparison(e.left, e.right, e.op, symbols, fallback)
        return ir.Atom(span_text(self.lines, e.span), rho, satisfied, (bounds.lo, bounds.hi), margin=margin,
                       op=e.op, scalar=scalar)

    def formula_ref(self, e: ast.Name, causal_clause: Optional[str]) -> ir.Formula:
        kind = self.s.kinds.get(e.id, (None,))[0]
        if kind != FORMULA:
            if kind in (STATE, LET, CONST, ACTION):
                self.d.add("E116", f"'{e.id}' is {_a(kind)}, a number, not a condition", e.span,
                           hint=f"compare it, for example `{e.id} > 0`")
            elif kind == REGION:
                self.d.add("E116", f"'{e.id}' is a region, not a condition", e.span, hint=f"write `in {e.id}`")
            else:
                self.n.unknown(e.id, e.span, (FORMULA,))
            raise _Unresolved
        self.s.used.add(e.id)
        node = self.formula_ir(e.id)
        if node is None:
            raise _Unresolved
        if causal_clause and not ir.is_causal(node):
            self.d.add("E107", f"'{causal_clause}' must be causal, but formula '{e.id}' uses a future operator", e.span,
                       hint="an agent cannot see the future: use past operators (historically, once, since)")
            raise _Unresolved
        return node

    def clause_condition(self, clause: ast.Clause, name: str) -> ir.Formula:
        return self.limited(self.condition(clause.value, name), clause.span, f"`{name}`")

    def limited(self, node: ir.Formula, span: Span, what: str) -> ir.Formula:
        """``node`` if its evaluators can walk it: E001 at ``span`` where formulas used through
        formulas nest too deep, or expand (a formula used twice counts twice) too far."""
        depth, size = ir.measure(node, self._measure_memo)
        if depth > LIMITS.formula_depth:
            self.d.add("E001", f"{what} nests {depth} operators deep, counting the formulas it uses; "
                       f"the limit is {LIMITS.formula_depth}", span, hint="a chain of `and` or `or` does not count: "
                       "write long conditions as such chains rather than nesting them")
            raise _Unresolved
        if size > LIMITS.formula_size:
            self.d.add("E001", f"{what} expands to {size:,} operators, counting a formula each time it is used; "
                       f"the limit is {LIMITS.formula_size:,}", span,
                       hint="a formula used twice in one condition is evaluated twice: use it once")
            raise _Unresolved
        return node

    def formula_ir(self, name: str) -> Optional[ir.Formula]:
        if name in self._formula_ir:
            return self._formula_ir[name]
        decl = self._formula_decls[name]
        if name in self._formula_stack:
            self.d.add("E120", f"formula '{name}' is defined in terms of itself", decl.name_span)
            self._formula_ir[name] = None
            return None
        self._formula_stack.append(name)
        try:
            node = self.limited(self.condition(decl.body), decl.name_span, f"formula '{name}'")
        except _Unresolved:
            node = None
        finally:
            self._formula_stack.pop()
        if name not in self._formula_ir:
            self._formula_ir[name] = node
        return self._formula_ir[name]


#: What to do with a time in seconds (or `dt`) in a map without `dt`.
STEPS_ONLY_HINT = "write times in steps (`deadline 200`), or give the system `dt = ...` (seconds per step)"
#: Where a let that reads actions can be used, and where not.
ACTION_LET_HINT = ("a let that reads actions can be used in the ode/map equations and other lets; regions, "
                   "formulas, asap and avoid see the states only")


def _kind_hint(name: str, kind: str, wanted: tuple[str, ...]) -> Optional[str]:
    if kind == REGION:
        return f"write `in {name}` for the condition of being in the region"
    if kind == FORMULA and REGION in wanted:
        return "`in` takes a region; use the formula's name on its own"
    return None


def _context_hint(context: str) -> Optional[str]:
    if context == "a constant expression":
        return "bounds, dt, centres, radii and settings must be constants"
    if context == "a formula":
        return "formulas are over the trace of states; actions are not part of it"
    return None
