"""The checker: AST to :class:`~asap_dsl.model.ProgramModel`, reporting every problem at once.

It resolves names (suggesting the closest declared one), tells conditions from numbers, folds
constants, converts times to steps, checks causality and builds the formula IR. It never stops at
the first problem: each part is checked on its own and a broken part is left out of the model,
so that the rest still gets checked. Model-level rules (overlaps, bounds, unused names, ...) are
lint rules in :mod:`asap_dsl.lint`.

The checks are in three parts: names, numbers, times and conditions here; the system and its
regions in :mod:`asap_dsl.checker_system`; formula declarations and tasks in
:mod:`asap_dsl.checker_tasks`. :class:`Checker` puts them together over one shared state.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from . import ast
from .diagnostics import Collector, Span, span_text
from .diagnostics import closest as _closest
from .checker_common import (ACTION, CONST, FORMULA, LET, REGION, STATE, _FUTURE_TO_PAST, _MAX_STEPS, _a, _fmt,
                             _Unresolved)
from .checker_system import SystemChecks
from .checker_tasks import TaskChecks
from .domains import DomainChecker
from .expr import (BUILTIN_CONSTANTS, FUNCTION_ARITY, Symbols, compile_scalar, evaluate_constant, interval_range,
                   scalar_comparison)
from .limits import LIMITS
from .model import ActionVar, FormulaModel, ProgramModel, RegionModel, StateVar, TaskModel
from .rewards import FLOAT32_MAX
from .stl import ir


class Checker(SystemChecks, TaskChecks):
    def __init__(self, module: ast.Module, source: str, diag: Collector):
        self.m = module
        self.source = source
        self.d = diag
        self.lines = source.splitlines()
        self.kinds: dict[str, tuple[str, Span]] = {}
        self.used: set[str] = set()
        self.consts: dict[str, float] = {}
        self.states: list[StateVar] = []
        self.actions: list[ActionVar] = []
        self.lets: dict[str, ast.Expr] = {}
        self._measure_memo: dict = {}  # ir.measure's, shared: formulas are measured once
        self._domain_reported: set[Span] = set()  # domain issues already reported (see check_domains)
        self._domains: Optional[tuple[DomainChecker, DomainChecker]] = None  # over states; states and actions
        self.dt: Optional[float] = None
        self._const_failed: set[str] = set()
        self.regions: dict[str, RegionModel] = {}
        self.formulas: dict[str, FormulaModel] = {}
        self._formula_ir: dict[str, Optional[ir.Formula]] = {}
        self._formula_stack: list[str] = []
        self._region_decls = {r.name: r for r in module.regions}
        self._formula_decls = {f.name: f for f in module.formulas}

    # ------------------------------------------------------------------ helpers
    def text(self, span: Span) -> str:
        return span_text(self.lines, span)

    def declare(self, name: str, kind: str, span: Span) -> bool:
        if name in BUILTIN_CONSTANTS:
            self.d.add("E102", f"'{name}' is a built-in constant and cannot be redeclared", span)
            return False
        if name in self.kinds:
            prev_kind, prev = self.kinds[name]
            self.d.add("E102", f"'{name}' is already declared as a {prev_kind} at line {prev.line}", span)
            return False
        self.kinds[name] = (kind, span)
        return True

    def unknown(self, name: str, span: Span, wanted: tuple[str, ...]) -> None:
        candidates = [n for n, (k, _) in self.kinds.items() if k in wanted]
        if CONST in wanted:
            candidates += list(BUILTIN_CONSTANTS)
        suggestion = _closest(name, candidates)
        what = " or ".join(dict.fromkeys(wanted)) if wanted else "name"
        msg = f"unknown {what} '{name}'"
        hint = f"did you mean '{suggestion}'?" if suggestion else None
        if name in self.kinds:
            kind = self.kinds[name][0]
            self.d.add("E103", f"'{name}' is {_a(kind)}, not a {what}", span, hint=_kind_hint(name, kind, wanted))
            return
        self.d.add("E101", msg, span, hint)

    def not_a_state(self, name: str, span: Span, states: list[str], where: str, code: str, role: str) -> None:
        """Report ``name`` where a state must stand: E101 with the closest state if it is no name
        at all, else ``code`` saying what it is and what ``role`` needs."""
        kind = self.kinds.get(name, (None,))[0]
        if kind is None:
            sug = _closest(name, states)
            self.d.add("E101", f"unknown state '{name}' in {where}", span, hint=f"did you mean '{sug}'?" if sug else None)
        else:
            self.d.add(code, f"'{name}' is {_a(kind)}; {role}", span)

    # ------------------------------------------------------------------ expressions (numbers)
    def number(self, e: ast.Expr, allowed: tuple[str, ...], context: str) -> None:
        """Check that ``e`` is a numeric expression over names of the ``allowed`` kinds."""
        if isinstance(e, (ast.Number, ast.Infinity)):
            return
        if isinstance(e, ast.Duration):  # `substeps = 2s`: a time where only a number can stand
            self.d.add("E117", f"{context} takes a number, not a time", e.span,
                       hint="times (1s, 500ms) are for deadlines, tolerances, windows and episode lengths")
            raise _Unresolved
        if isinstance(e, ast.Name):
            if e.id in BUILTIN_CONSTANTS:
                return
            kind = self.kinds.get(e.id, (None,))[0]
            if kind in allowed:
                self.used.add(e.id)
                if kind == CONST and e.id not in self.consts:
                    if e.id not in self._const_failed:
                        self.d.add("E101", f"constant '{e.id}' is used before it is declared", e.span,
                                   hint="a constant may use the constants declared before it")
                    raise _Unresolved
                if kind == LET and e.id not in self.lets:
                    raise _Unresolved  # reported where the let is declared
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
            errors = 0
            for side in reversed(operands):
                try:
                    self.number(side, allowed, context)
                except _Unresolved:
                    errors += 1
            if errors:
                raise _Unresolved
            return
        if isinstance(e, ast.Call):
            if e.func not in FUNCTION_ARITY:
                sug = _closest(e.func, FUNCTION_ARITY)
                self.d.add("E118", f"unknown function '{e.func}'", e.func_span,
                           hint=f"did you mean '{sug}'?" if sug else "the functions are " + ", ".join(FUNCTION_ARITY))
                raise _Unresolved
            arity = FUNCTION_ARITY[e.func]
            if (arity is not None and len(e.args) != arity) or (arity is None and not e.args):
                want = f"{arity} argument{'s' if arity != 1 else ''}" if arity else "at least one argument"
                self.d.add("E104", f"{e.func}() takes {want}, given {len(e.args)}", e.span)
                raise _Unresolved
            errors = 0
            for a in e.args:
                try:
                    self.number(a, allowed, context)
                except _Unresolved:
                    errors += 1
            if errors:
                raise _Unresolved
            return
        self.d.add("E116", f"a condition cannot be used as a number in {context}", e.span)
        raise _Unresolved

    def constant(self, e: ast.Expr, what: str) -> float:
        """Fold a constant expression; report and raise if it reads anything but constants."""
        self.number(e, (CONST,), what if isinstance(e, ast.Duration) else "a constant expression")
        value = evaluate_constant(e, self.consts)
        if math.isnan(value):
            self.d.add("E117", f"{what} is not a real number (check divisions, logarithms and roots)", e.span)
            raise _Unresolved
        return value

    def finite_constant(self, e: ast.Expr, what: str) -> float:
        """A constant that a reward computes with: infinity there gives inf - inf = NaN rewards,
        and SB3 stores rewards as float32 (at most about 3.4e38)."""
        value = self.constant(e, what)
        if not abs(value) <= FLOAT32_MAX:
            self.d.add("E117", f"{what} must be a finite number within ±3.4e38 (a float32 reward), not {_fmt(value)}", e.span)
            raise _Unresolved
        return value

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
                self.d.add("E106", f"{what} {_fmt(d.value)} is not a whole number of steps", d.span,
                           hint="give a whole number of steps, or seconds with a unit such as 1.5s")
                raise _Unresolved
            if d.value > _MAX_STEPS:
                self.d.add("E117", f"{what} {_fmt(d.value)} is more than {_MAX_STEPS:.0e} steps", d.span)
                raise _Unresolved
            return int(d.value)
        seconds = d.value / 1000.0 if d.unit == "ms" else d.value
        if self.dt is None:
            self.d.add("E114", f"{what} is given in seconds, but the system has no valid dt to convert it", d.span)
            raise _Unresolved
        n = seconds / self.dt
        if not math.isfinite(n) or n > _MAX_STEPS:
            self.d.add("E117", f"{what} {_fmt(d.value)}{d.unit} is more than {_MAX_STEPS:.0e} steps of dt = {_fmt(self.dt)}", d.span)
            raise _Unresolved
        if abs(n - round(n)) > 1e-9 * max(1.0, abs(n)):
            self.d.add("E106", f"{what} {_fmt(d.value)}{d.unit} is {n:.6g} steps of dt = {_fmt(self.dt)}, not a whole number",
                       d.span, hint=f"use a multiple of {_fmt(self.dt)}s")
            raise _Unresolved
        return int(round(n))

    def interval(self, syn: Optional[ast.IntervalSyntax]) -> ir.Interval:
        if syn is None:
            return ir.Interval(0, None)
        errors = 0
        lo = hi = None
        try:
            lo = self.steps(syn.lo, "the interval's lower bound")
        except _Unresolved:
            errors += 1
        try:
            hi = self.steps(syn.hi, "the interval's upper bound", allow_inf=True)
        except _Unresolved:
            errors += 1
        if errors:
            raise _Unresolved
        if hi is not None and lo > hi:
            self.d.add("E105", f"the interval [{lo}, {hi}] (in steps) has its lower bound above its upper bound", syn.span,
                       hint=f"write [{hi}, {lo}]")
            raise _Unresolved
        return ir.Interval(lo, hi)

    # ------------------------------------------------------------------ conditions (formulas)
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
            built, errors = [], 0
            for side in reversed(operands):
                try:
                    built.append(self.condition(side, causal_clause))
                except _Unresolved:
                    errors += 1
            if errors:
                raise _Unresolved
            if e.op == "implies":
                return ir.Implies(*built)
            return ir.balanced(ir.And if e.op == "and" else ir.Or, built)
        if isinstance(e, (ast.Temporal, ast.Temporal2)):
            errors = 0
            if causal_clause and e.op in _FUTURE_TO_PAST:
                self.d.add("E107", f"'{causal_clause}' must be causal, but '{e.op}' looks into the future", e.op_span,
                           hint=f"an agent cannot see the future: use the past form '{_FUTURE_TO_PAST[e.op]}'")
                errors += 1
            interval = None
            try:
                interval = self.interval(e.interval)
            except _Unresolved:
                errors += 1
            args = (e.arg,) if isinstance(e, ast.Temporal) else (e.left, e.right)
            built = []
            for a in args:
                try:
                    built.append(self.condition(a, causal_clause))
                except _Unresolved:
                    errors += 1
            if errors:
                raise _Unresolved
            cls = {"always": ir.Always, "eventually": ir.Eventually, "historically": ir.Historically,
                   "once": ir.Once, "until": ir.Until, "since": ir.Since}[e.op]
            return cls(interval, *built)
        # A number where a condition is expected.
        self.d.add("E116", "a number cannot be used as a condition", e.span,
                   hint="compare it, for example `x > 0`")
        raise _Unresolved

    def region_atom(self, e: ast.InRegion) -> ir.Formula:
        if e.region not in self.regions:
            if e.region in self._region_decls:
                raise _Unresolved  # the region itself has errors, reported there
            self.unknown(e.region, e.name_span, (REGION,))
            raise _Unresolved
        self.used.add(e.region)
        region = self.regions[e.region]
        return ir.Atom(f"in {e.region}", region.robustness, region.satisfied, self.region_bounds(region), e.region,
                       scalar=region.scalar_form(self.symbols()))

    def compare_atom(self, e: ast.Compare) -> ir.Formula:
        if e.op in ("==", "!="):
            self.d.add("E115", f"'{e.op}' between real signals cannot be measured by robustness", e.op_span,
                       hint="write `abs(a - b) <= eps`" if e.op == "==" else "write `abs(a - b) > eps`")
            raise _Unresolved
        errors = 0
        for side in (e.left, e.right):
            try:
                self.number(side, (CONST, STATE, LET), "a formula")
            except _Unresolved:
                errors += 1
        if errors:
            raise _Unresolved
        # rho of `a < b` is b - a; of `a > b` is a - b.
        margin = ast.Binary("-", e.right, e.left, e.span) if e.op in ("<", "<=") else ast.Binary("-", e.left, e.right, e.span)
        symbols = self.symbols()
        rho = compile_scalar(margin, symbols)
        left, right = compile_scalar(e.left, symbols), compile_scalar(e.right, symbols)
        op = {"<": np.less, "<=": np.less_equal, ">": np.greater, ">=": np.greater_equal}[e.op]

        def satisfied(states, _l=left, _r=right, _op=op):
            return _op(_l(states), _r(states))

        self.check_domains([e.left, e.right], "this condition")
        bounds = interval_range(margin, symbols, self.state_box())
        def fallback(row, _rho=rho, _sat=satisfied):
            s = np.asarray(row, dtype=np.float64)[None]
            with np.errstate(all="ignore"):
                return float(_rho(s)[0]), bool(_sat(s)[0])

        scalar = scalar_comparison(e.left, e.right, e.op, symbols, fallback)
        return ir.Atom(self.text(e.span), rho, satisfied, (bounds.lo, bounds.hi), margin=margin, scalar=scalar)

    def formula_ref(self, e: ast.Name, causal_clause: Optional[str]) -> ir.Formula:
        kind = self.kinds.get(e.id, (None,))[0]
        if kind != FORMULA:
            if kind in (STATE, LET, CONST, ACTION):
                self.d.add("E116", f"'{e.id}' is {_a(kind)}, a number, not a condition", e.span,
                           hint=f"compare it, for example `{e.id} > 0`")
            elif kind == REGION:
                self.d.add("E116", f"'{e.id}' is a region, not a condition", e.span, hint=f"write `in {e.id}`")
            else:
                self.unknown(e.id, e.span, (FORMULA,))
            raise _Unresolved
        self.used.add(e.id)
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

    # ------------------------------------------------------------------ system
    def symbols(self) -> Symbols:
        return Symbols(dict(self.consts), {s.name: s.index for s in self.states},
                       {a.name: a.index for a in self.actions}, dict(self.lets))

    def check_domains(self, exprs, where: str, actions: bool = False) -> None:
        """E124 where an operation surely leaves its domain over the state space, W209 where it
        may (interval analysis, :mod:`asap_dsl.domains`). Lets are checked once, on their own,
        before any use; an issue is reported once, at its place."""
        if self._domains is None:  # built once the states, actions and lets are known
            symbols, box = self.symbols(), self.state_box()
            self._domains = (DomainChecker(symbols, box), DomainChecker(symbols, box, [(a.low, a.high) for a in self.actions]))
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
                           hint="narrow the state space, or guard the argument (for example sqrt(abs(x)) or max(x, 1e-9))")

    def state_box(self) -> list[tuple[float, float]]:
        return [(s.low, s.high) for s in self.states]

    # ------------------------------------------------------------------ all
    def run(self) -> Optional[ProgramModel]:
        system = self.check_system()
        self.check_regions()
        self.check_formulas()
        tasks: dict[str, TaskModel] = {}
        for t in self.m.tasks:
            if self.kinds.get(t.name, (None, None))[1] != t.name_span:
                continue
            model = self.check_task(t)
            if model is not None:
                tasks[t.name] = model
        if system is None:
            return None
        # With errors elsewhere the model is partial (broken parts left out); lint rules still run
        # on it so that a file's problems are all reported at once, and the caller discards it.
        return ProgramModel(self.m.file, self.source, system, dict(self.regions), dict(self.formulas), tasks,
                            frozenset(self.used), dict(self.kinds))


def _kind_hint(name: str, kind: str, wanted: tuple[str, ...]) -> Optional[str]:
    if kind == REGION:
        return f"write `in {name}` for the condition of being in the region"
    if kind == FORMULA and REGION in wanted:
        return "`in` takes a region; use the formula's name on its own"
    return None


def _context_hint(context: str) -> Optional[str]:
    if context == "a constant expression":
        return "bounds, dt, centres, radii and settings must be constants"
    if context.startswith("let"):
        return "a let is a signal over states: it cannot read actions"
    if context == "a formula":
        return "formulas are over the trace of states; actions are not part of it"
    return None


def check(module: ast.Module, source: str, diag: Collector) -> Optional[ProgramModel]:
    """Check a parsed module; diagnostics go to ``diag``.

    The model is None when there is no usable system; it is partial when ``diag`` has errors.
    """
    return Checker(module, source, diag).run()
