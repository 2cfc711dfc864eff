"""The checker: AST to :class:`~asap_dsl.model.ProgramModel`, reporting every problem at once.

It resolves names (suggesting the closest declared one), tells conditions from numbers, folds
constants, converts times to steps, checks causality and builds the formula IR. It never stops at
the first problem: each part is checked on its own and a broken part is left out of the model,
so that the rest still gets checked. Model-level rules (overlaps, bounds, unused names, ...) are
lint rules in :mod:`asap_dsl.lint`.
"""

from __future__ import annotations

import math
from typing import Callable, Iterable, Optional

import numpy as np

from . import ast
from .diagnostics import Collector, Span, span_text
from .diagnostics import closest as _closest
from .expr import BUILTIN_CONSTANTS, FUNCTION_ARITY, Symbols, names_in, nodes_in, compile_batched, compile_scalar, evaluate_constant, interval_range, scalar_comparison
from .domains import DomainChecker
from .rewards import FLOAT32_MAX
from .intervals import Interval
from .limits import LIMITS
from .model import (ActionVar, FormulaModel, Integrator, ProgramModel, RegionModel, RewardModel, StateVar,
                    SystemModel, TaskModel)
from .stl import ir

ALGORITHMS = ("sac", "td3", "ddpg", "ppo", "a2c")
REWARDS = {"asap": (), "rho": ("window",), "distance": ("lambda_t", "lambda_o", "base")}
INTEGRATORS = {"rk4": ("substeps",), "euler": ("substeps",), "exact": ()}
TRAIN_SETTINGS = {
    "algo": "str", "steps": "int", "seed": "int", "preset": "str", "n_envs": "int",
    "learning_rate": "float", "batch_size": "int", "buffer_size": "int", "gamma": "float",
    "tau": "float", "learning_starts": "int", "train_freq": "int", "gradient_steps": "int",
    "n_steps": "int", "ent_coef": "float", "gae_lambda": "float", "n_epochs": "int",
    "vf_coef": "float", "max_grad_norm": "float", "eval_episodes": "int",
}
OBSERVE_ITEMS = ("state", "time")
_MAX_STEPS = 1e9  # a time of more steps than this is a typo, not an episode
_FUTURE_TO_PAST = {"always": "historically", "eventually": "once", "until": "since"}

# Kinds of names.
CONST, STATE, ACTION, LET, REGION, FORMULA, TASK, SYSTEM = (
    "constant", "state", "action", "let", "region", "formula", "task", "system")


class _Unresolved(Exception):
    """A sub-expression had errors (already reported); the enclosing item is left out."""


class Checker:
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

    def region_bounds(self, region: RegionModel) -> tuple[float, float]:
        # A state's interval is its space (looked up, so that a ball over n states costs O(n));
        # a let's comes from interval analysis over the state box (built once).
        spaces = {s.name: Interval(s.low, s.high) for s in self.states}
        box = symbols = None
        coords = []
        for c in region.coords:
            if c in spaces:
                coords.append(spaces[c])
                continue
            if box is None:
                symbols, box = self.symbols(), self.state_box()
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

    def range_(self, r: ast.Range, what: str) -> tuple[float, float]:
        values = []
        errors = 0
        for e in (r.lo, r.hi):
            try:
                values.append(self.constant(e, what))
            except _Unresolved:
                errors += 1
        if errors:
            raise _Unresolved
        lo, hi = values
        if lo > hi:
            self.d.add("E105", f"{what} [{_fmt(lo)}, {_fmt(hi)}] has its lower bound above its upper bound", r.span,
                       hint=f"write [{_fmt(hi)}, {_fmt(lo)}]")
            raise _Unresolved
        return lo, hi

    def check_system(self) -> Optional[SystemModel]:
        if not self.m.systems:
            self.d.add("E114", "the file declares no system", Span(1, 1, 1, 2),
                       hint="a spec starts with `system NAME { state ..., action ..., dt = ..., ode { ... } }`")
            return None
        for extra in self.m.systems[1:]:
            self.d.add("E119", f"a file holds one system; '{extra.name}' is a second one", extra.name_span)
        sys = self.m.systems[0]
        self.declare(sys.name, SYSTEM, sys.name_span)
        # Declare every name first so that uses can say what a name is even out of order.
        for c in sys.consts:
            self.declare(c.name, CONST, c.name_span)
        for s in sys.states:
            self.declare(s.name, STATE, s.name_span)
        for a in sys.actions:
            self.declare(a.name, ACTION, a.name_span)
        for lt in sys.lets:
            self.declare(lt.name, LET, lt.name_span)

        if not sys.dt:
            self.d.add("E114", f"system '{sys.name}' has no `dt = ...` (seconds per step)", sys.name_span)
        for extra in sys.dt[1:]:
            self.d.add("E119", "dt is given more than once", extra.span)
        # `dt = ...` is a constant like the others, read as `dt` by any expression: in order with the
        # constants (a constant may use those before it, dt included).
        steps: list = [(c.span.line, c.span.column, c) for c in sys.consts]
        if sys.dt:
            self.declare("dt", CONST, sys.dt[0].span)
            self.used.add("dt")  # never reported unused: it is the system's step
            steps.append((sys.dt[0].span.line, sys.dt[0].span.column, sys.dt[0]))
        for _, _, c in sorted(steps, key=lambda item: item[:2]):
            if not isinstance(c, ast.ConstDecl):
                self.check_dt(c)
                continue
            if self.kinds.get(c.name, (None, None))[1] != c.name_span:
                continue
            try:
                self.consts[c.name] = self.constant(c.value, f"constant '{c.name}'")
            except _Unresolved:
                self._const_failed.add(c.name)

        for s in sys.states:
            if self.kinds.get(s.name, (None, None))[1] != s.name_span:
                continue
            try:
                lo, hi = self.range_(s.space, f"the state space of '{s.name}'")
                if not lo < hi:
                    self.d.add("E117", f"the state space of '{s.name}' is empty or a single point", s.space.span)
                    raise _Unresolved
                ilo, ihi = (lo, hi) if s.init is None else self.range_(s.init, f"the init range of '{s.name}'")
            except _Unresolved:
                lo, hi, ilo, ihi = -math.inf, math.inf, 0.0, 0.0
            self.states.append(StateVar(s.name, len(self.states), lo, hi, ilo, ihi, s.span, s.init.span if s.init else None))
        if not sys.states:
            self.d.add("E114", f"system '{sys.name}' declares no state", sys.name_span)

        for a in sys.actions:
            if self.kinds.get(a.name, (None, None))[1] != a.name_span:
                continue
            try:
                lo, hi = self.range_(a.bounds, f"the bounds of action '{a.name}'")
                if not (math.isfinite(lo) and math.isfinite(hi)):
                    self.d.add("E117", f"the bounds of action '{a.name}' must be finite", a.bounds.span)
            except _Unresolved:
                lo, hi = -1.0, 1.0
            self.actions.append(ActionVar(a.name, len(self.actions), lo, hi, a.span))

        # Lets: over states, constants and other lets (any order, no cycles).
        let_decls = {lt.name: lt for lt in sys.lets if self.kinds.get(lt.name, (None, None))[1] == lt.name_span}
        order = self._let_order(let_decls)
        for name in order:
            lt = let_decls[name]
            try:
                self.number(lt.value, (CONST, STATE, LET), f"let '{name}'")
                self.lets[name] = lt.value
            except _Unresolved:
                pass
        for name in self.lets:
            self.check_domains([self.lets[name]], f"let '{name}'")

        kind, equations, simulator, dyn_span = self.check_dynamics(sys)
        integrator = self.check_integrator(sys, kind)
        if equations:
            self.check_domains(equations, "the dynamics", actions=True)
        if self.dt is None or kind is None:
            return None
        return SystemModel(sys.name, tuple(self.states), tuple(self.actions), dict(self.consts), dict(self.lets),
                           self.dt, kind, equations, simulator, integrator, sys.span, dyn_span)

    def check_dt(self, e: ast.Expr) -> None:
        try:
            dt = self.constant(e, "dt")
        except _Unresolved:
            self._const_failed.add("dt")
            return
        if not dt > 0 or not math.isfinite(dt):
            self.d.add("E117", f"dt must be a positive number of seconds, not {_fmt(dt)}", e.span)
            self._const_failed.add("dt")
            return
        self.dt = dt
        self.consts["dt"] = dt

    def _let_order(self, decls: dict[str, ast.LetDecl]) -> list[str]:
        order, cyclic = dependency_order(list(decls), lambda n: (m.id for m in names_in(decls[n].value) if m.id in decls))
        for name in cyclic:
            self.d.add("E120", f"let '{name}' is defined in terms of itself", decls[name].name_span)
        return order

    def check_dynamics(self, sys: ast.System):
        if not sys.dynamics:
            self.d.add("E114", f"system '{sys.name}' has no dynamics: add `ode {{ ... }}`, `map {{ ... }}` or `simulator \"...\"`",
                       sys.name_span)
            return None, (), None, sys.span
        for extra in sys.dynamics[1:]:
            self.d.add("E119", "a system has exactly one dynamics (ode, map or simulator); this is a second one", extra.span)
        dyn = sys.dynamics[0]
        if isinstance(dyn, ast.SimulatorDecl):
            target = dyn.target.strip()
            if not target or (":" in target and (not target.split(":", 1)[0] or not target.split(":", 1)[1])):
                self.d.add("E117", f"simulator \"{dyn.target}\" is not a registered name or \"package.module:factory\"", dyn.span)
                return None, (), None, dyn.span
            return "simulator", (), target, dyn.span
        state_names = [s.name for s in self.states]
        given: dict[str, ast.Equation] = {}
        errors = 0
        prime = "'" if dyn.kind == "ode" else ""
        known = set(state_names)  # looked up once per equation: a set, or 20,000 states cost seconds
        for eq in dyn.equations:
            if eq.target not in known:
                kind = self.kinds.get(eq.target, (None,))[0]
                if kind is None:
                    sug = _closest(eq.target, state_names)
                    self.d.add("E101", f"unknown state '{eq.target}' in {dyn.kind}", eq.target_span,
                               hint=f"did you mean '{sug}'?" if sug else None)
                else:
                    self.d.add("E110", f"'{eq.target}' is {_a(kind)}; {dyn.kind} equations are for states", eq.target_span)
                errors += 1
                continue
            if eq.target in given:
                self.d.add("E110", f"state '{eq.target}' has a second equation (the first is at line {given[eq.target].span.line})",
                           eq.target_span)
                errors += 1
                continue
            given[eq.target] = eq
            try:
                self.number(eq.value, (CONST, STATE, ACTION, LET), f"the {dyn.kind} equation of '{eq.target}'")
            except _Unresolved:
                errors += 1
        for s in state_names:
            if s not in given:
                self.d.add("E109", f"state '{s}' has no equation in {dyn.kind}", dyn.span,
                           hint=f"add `{s}{prime} = ...`")
                errors += 1
        if errors:
            return None, (), None, dyn.span
        return dyn.kind, tuple(given[s].value for s in state_names), None, dyn.span

    def check_integrator(self, sys: ast.System, kind: Optional[str]) -> Integrator:
        if not sys.integrators:
            return Integrator()
        for extra in sys.integrators[1:]:
            self.d.add("E119", "the integrator is given more than once", extra.span)
        decl = sys.integrators[0]
        if kind in ("map", "simulator"):
            self.d.add("E119", f"an integrator applies to `ode` dynamics only, not to a {kind}", decl.span)
            return Integrator(span=decl.span)
        if decl.method not in INTEGRATORS:
            sug = _closest(decl.method, INTEGRATORS)
            self.d.add("E117", f"unknown integrator '{decl.method}'", decl.method_span,
                       hint=f"did you mean '{sug}'?" if sug else "choose rk4, euler or exact")
            return Integrator(span=decl.span)
        substeps = 4 if decl.method == "rk4" else 1
        for s in decl.settings:
            if s.name not in INTEGRATORS[decl.method]:
                self.d.add("E117", f"integrator {decl.method} has no setting '{s.name}'", s.name_span,
                           hint=f"it takes {', '.join(INTEGRATORS[decl.method]) or 'no settings'}")
                continue
            try:
                v = self.constant(s.value, "substeps")
            except _Unresolved:
                continue
            if not float(v).is_integer() or v < 1:
                self.d.add("E117", "substeps must be a whole number of at least 1", s.span)
                continue
            if v > LIMITS.substeps:  # every step of every environment would take that many evaluations
                self.d.add("E117", f"substeps = {_fmt(v)} is more than {LIMITS.substeps:,}", s.span,
                           hint="a few substeps integrate as accurately at a fraction of the cost; "
                           "`asapc --max-substeps N` raises the limit")
                continue
            substeps = int(v)
        return Integrator(decl.method, substeps if decl.method != "exact" else 1, decl.span)

    # ------------------------------------------------------------------ regions
    def check_regions(self) -> None:
        for r in self.m.regions:
            self.declare(r.name, REGION, r.name_span)
        for f in self.m.formulas:
            self.declare(f.name, FORMULA, f.name_span)
        for t in self.m.tasks:
            self.declare(t.name, TASK, t.name_span)
        state_names = [s.name for s in self.states]
        symbols = self.symbols()
        for r in self.m.regions:
            if self.kinds.get(r.name, (None, None))[1] != r.name_span:
                continue
            try:
                model = self.region(r, state_names)
            except _Unresolved:
                continue
            values = compile_batched([ast.Name(c, Span()) for c in model.coords], symbols)
            self.regions[r.name] = RegionModel(model.name, model.kind, model.coords, model.centre, model.radius,
                                               model.low, model.high, r.span, values)

    def coordinate(self, name: str, span: Span) -> None:
        kind = self.kinds.get(name, (None,))[0]
        if kind in (STATE, LET):
            if kind == LET and name not in self.lets:
                raise _Unresolved
            self.used.add(name)
            return
        if kind is None:
            self.unknown(name, span, (STATE, LET))
        else:
            self.d.add("E103", f"'{name}' is {_a(kind)}; a region is over states and lets", span)
        raise _Unresolved

    def region(self, r: ast.RegionDecl, state_names: list[str]) -> RegionModel:
        shape = r.shape
        errors = 0
        if isinstance(shape, ast.Ball):
            coords: list[str] = []
            centre: list[float] = []
            if shape.named:
                for c in shape.centre:
                    if c.name in coords:
                        self.d.add("E102", f"'{c.name}' appears twice in the centre of region '{r.name}'", c.span)
                        errors += 1
                        continue
                    try:
                        self.coordinate(c.name, c.span)
                        coords.append(c.name)
                        centre.append(self.constant(c.value, "a ball centre"))
                    except _Unresolved:
                        errors += 1
                if not shape.centre:
                    self.d.add("E104", f"the centre of region '{r.name}' names no variable", shape.centre_span)
                    errors += 1
            else:
                if len(shape.centre) != len(state_names):
                    self.d.add("E104", f"the centre of region '{r.name}' has {len(shape.centre)} entries, but the system has "
                               f"{len(state_names)} states ({', '.join(state_names)})", shape.centre_span,
                               hint="give one entry per state in declaration order, or name them: ball({x: 1, y: 2}, r)")
                    errors += 1
                for c in shape.centre:
                    try:
                        centre.append(self.constant(c, "a ball centre"))
                    except _Unresolved:
                        errors += 1
                coords = list(state_names)
            try:
                radius = self.constant(shape.radius, "a ball radius")
                if not radius > 0:
                    self.d.add("E117", f"the radius of region '{r.name}' must be positive, not {_fmt(radius)}", shape.radius.span)
                    errors += 1
            except _Unresolved:
                errors += 1
                radius = 0.0
            if errors:
                raise _Unresolved
            return RegionModel(r.name, "ball", tuple(coords), tuple(centre), radius)
        coords, lows, highs = [], [], []
        if not shape.sides:
            self.d.add("E104", f"box '{r.name}' bounds no variable", shape.span)
            raise _Unresolved
        for side in shape.sides:
            if side.var in coords:
                self.d.add("E102", f"'{side.var}' is bounded twice in box '{r.name}'", side.span)
                errors += 1
                continue
            try:
                self.coordinate(side.var, side.span)
                lo, hi = self.range_(side.bounds, f"the side '{side.var}' of box '{r.name}'")
                coords.append(side.var)
                lows.append(lo)
                highs.append(hi)
            except _Unresolved:
                errors += 1
        if errors:
            raise _Unresolved
        return RegionModel(r.name, "box", tuple(coords), low=tuple(lows), high=tuple(highs))

    # ------------------------------------------------------------------ formulas and tasks
    def check_formulas(self) -> None:
        # In dependency order, so that a formula's references are built before it and building
        # one never recurses through a chain of formulas (which may be as long as the file).
        decls = {f.name: f for f in self.m.formulas if self.kinds.get(f.name, (None, None))[1] == f.name_span}
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
                self.formulas[f.name] = FormulaModel(f.name, node, f.span)

    def check_task(self, t: ast.TaskDecl) -> Optional[TaskModel]:
        clauses: dict[str, ast.Clause] = {}
        for c in t.clauses:
            if c.keyword in clauses:
                self.d.add("E119", f"task '{t.name}' gives `{c.keyword}` twice (first at line {clauses[c.keyword].span.line})", c.span)
                continue
            clauses[c.keyword] = c
        errors = 0
        for required in ("asap", "deadline"):
            if required not in clauses:
                self.d.add("E114", f"task '{t.name}' has no `{required}` clause", t.name_span,
                           hint="`asap FORMULA` says what to fulfil as soon as possible" if required == "asap"
                           else "`deadline N` gives the longest episode in steps (or seconds, `3s`)")
                errors += 1

        def attempt(fn: Callable, *args, default=None):
            nonlocal errors
            try:
                return fn(*args)
            except _Unresolved:
                errors += 1
                return default

        asap = attempt(self.clause_condition, clauses["asap"], "asap") if "asap" in clauses else None
        avoid = attempt(self.clause_condition, clauses["avoid"], "avoid") if "avoid" in clauses else None
        deadline = attempt(self.positive_steps, clauses["deadline"].value, "the deadline") if "deadline" in clauses else None
        if deadline is not None and deadline > LIMITS.deadline_steps:
            # Every episode, evaluation and oracle horizon is this long: beyond it nothing finishes.
            self.d.add("E117", f"a deadline of {deadline:,} steps is more than {LIMITS.deadline_steps:,}",
                       clauses["deadline"].span, hint="a larger dt makes the same time fewer steps; "
                       "`asapc --max-deadline STEPS` raises the limit")
            errors += 1
            deadline = None
        tolerances: tuple[int, ...] = (deadline,) if deadline else ()
        if "tolerances" in clauses:
            tolerances = tuple(attempt(self.positive_steps, d, "a tolerance", default=0) for d in clauses["tolerances"].value)
        episode = (deadline, deadline) if deadline else (1, 1)
        if "episode" in clauses:
            lo_d, hi_d = clauses["episode"].value
            lo = attempt(self.positive_steps, lo_d, "the shortest episode", default=1)
            hi = attempt(self.positive_steps, hi_d, "the longest episode", default=1)
            if lo and hi and lo > hi:
                self.d.add("E105", f"the episode range {lo}..{hi} has its lower bound above its upper bound", clauses["episode"].span)
                errors += 1
            episode = (lo or 1, hi or 1)
        reward = attempt(self.reward, clauses["reward"].value, asap, avoid) if "reward" in clauses else RewardModel()
        asap_regions = ir.positive_regions(asap) if asap is not None else ()
        if reward is not None and reward.kind == "distance" and asap is not None and not asap_regions:
            self.d.add("E117", "reward distance(...) measures the distance to the `asap` region, but `asap` names no region",
                       clauses["reward"].span, hint="write `asap in REGION` (possibly with more conditions), or use reward asap or rho")
            errors += 1
        r_sat = None
        if "r_sat" in clauses:
            value = clauses["r_sat"].value
            if not (isinstance(value, ast.Name) and value.id == "auto"):
                r_sat = attempt(self.finite_constant, value, "r_sat")
        observe = ("state",)
        if "observe" in clauses:
            observe = attempt(self.observe, clauses["observe"].value, default=("state",))
        train = attempt(self.train, clauses["train"].value, default={}) if "train" in clauses else {}
        init_box = attempt(self.task_init, clauses["init"].value) if "init" in clauses else None
        if errors or asap is None or deadline is None:
            return None
        return TaskModel(
            t.name, asap, avoid, deadline, tolerances, episode, reward or RewardModel(), r_sat, observe, train, t.span,
            {k: c.span for k, c in clauses.items()},
            asap_regions, ir.positive_regions(avoid) if avoid is not None else (), init_box,
        )

    def task_init(self, box: ast.Box) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """``init box(theta in [a, b], ...)``: the task's initial box, each named state's range
        replacing the system's (the others keep theirs), with the checks of a state's `init`."""
        by_name = {s.name: s for s in self.states}
        low = [s.init_low for s in self.states]
        high = [s.init_high for s in self.states]
        seen: dict[str, Span] = {}
        errors = 0
        if not box.sides:
            self.d.add("E117", "`init box()` names no state", box.span, hint="write init box(x in [a, b], ...)")
            raise _Unresolved
        for side in box.sides:
            state = by_name.get(side.var)
            if state is None:
                kind = self.kinds.get(side.var, (None,))[0]
                if kind is None:
                    sug = _closest(side.var, list(by_name))
                    self.d.add("E101", f"unknown state '{side.var}' in the task's init box", side.span,
                               hint=f"did you mean '{sug}'?" if sug else None)
                else:
                    self.d.add("E103", f"'{side.var}' is {_a(kind)}; an initial box is over states", side.span)
                errors += 1
                continue
            if side.var in seen:
                self.d.add("E102", f"state '{side.var}' is given twice in the init box (first at line {seen[side.var].line})",
                           side.span)
                errors += 1
                continue
            seen[side.var] = side.span
            try:
                lo, hi = self.range_(side.bounds, f"the init range of '{side.var}'")
            except _Unresolved:
                errors += 1
                continue
            if lo < state.low or hi > state.high:
                self.d.add("E108", f"the init range [{_fmt(lo)}, {_fmt(hi)}] of '{side.var}' is not inside its state space "
                           f"[{_fmt(state.low)}, {_fmt(state.high)}]", side.bounds.span)
                errors += 1
                continue
            if not (math.isfinite(lo) and math.isfinite(hi) and math.isfinite(hi - lo)):
                self.d.add("E122", f"the init range [{_fmt(lo)}, {_fmt(hi)}] of '{side.var}' cannot be sampled uniformly: "
                           "it must be finite", side.bounds.span)
                errors += 1
                continue
            low[state.index], high[state.index] = lo, hi
        if errors:
            raise _Unresolved
        return tuple(low), tuple(high)

    def positive_steps(self, d: ast.Duration, what: str) -> int:
        n = self.steps(d, what)
        if n is None or n < 1:
            self.d.add("E117", f"{what} must be at least one step", d.span)
            raise _Unresolved
        return n

    def reward(self, syn: ast.RewardSyntax, asap, avoid) -> RewardModel:
        if syn.kind not in REWARDS:
            sug = _closest(syn.kind, REWARDS)
            self.d.add("E117", f"unknown reward '{syn.kind}'", syn.span,
                       hint=f"did you mean '{sug}'?" if sug else "choose asap, rho, rho(window = D) or distance(...)")
            raise _Unresolved
        params: dict[str, float] = {}
        for s in syn.settings:
            if s.name not in REWARDS[syn.kind]:
                self.d.add("E117", f"reward {syn.kind} has no setting '{s.name}'", s.name_span,
                           hint=f"it takes {', '.join(REWARDS[syn.kind]) or 'no settings'}")
                raise _Unresolved
            if s.name == "window":
                if isinstance(s.value, ast.Duration):  # rho(window = 1s)
                    params["window"] = self.positive_steps(s.value, "the reward window")
                elif isinstance(s.value, ast.Number):
                    params["window"] = self.positive_steps(ast.Duration(s.value.value, "steps", s.value.span), "the reward window")
                else:
                    params["window"] = self.constant(s.value, "the reward window")
                    if not float(params["window"]).is_integer() or params["window"] < 1:
                        self.d.add("E117", "the reward window must be a whole number of steps, at least 1", s.span)
                        raise _Unresolved
                    params["window"] = int(params["window"])
            else:
                params[s.name] = self.finite_constant(s.value, f"the reward setting {s.name}")
        if syn.kind == "distance":
            defaults = {"lambda_t": 1.0, "lambda_o": 1.0, "base": 0.0}
            params = {**defaults, **params}
        return RewardModel(syn.kind, params, syn.span)

    def observe(self, items) -> tuple[str, ...]:
        names = []
        for name, span in items:
            if name not in OBSERVE_ITEMS:
                sug = _closest(name, OBSERVE_ITEMS)
                self.d.add("E117", f"cannot observe '{name}'", span, hint=f"did you mean '{sug}'?" if sug else "observe state or state, time")
                raise _Unresolved
            if name in names:
                self.d.add("E117", f"'{name}' is observed twice", span)
                raise _Unresolved
            names.append(name)
        if names[0] != "state":
            self.d.add("E117", "the observation starts with the state: write `observe state, time`", items[0][1])
            raise _Unresolved
        return tuple(names)

    def train(self, settings) -> dict:
        out: dict = {}
        errors = 0
        for s in settings:
            if s.name not in TRAIN_SETTINGS:
                sug = _closest(s.name, TRAIN_SETTINGS)
                self.d.add("E117", f"unknown training setting '{s.name}'", s.name_span,
                           hint=f"did you mean '{sug}'?" if sug else "settings: " + ", ".join(TRAIN_SETTINGS))
                errors += 1
                continue
            kind = TRAIN_SETTINGS[s.name]
            value = s.value
            if kind == "str":
                text = value[1:-1] if isinstance(value, str) else (value.id if isinstance(value, ast.Name) else None)
                if text is None:
                    self.d.add("E117", f"'{s.name}' takes a name, such as `{s.name} = sac`", s.span)
                    errors += 1
                    continue
                if s.name == "algo" and text not in ALGORITHMS:
                    sug = _closest(text, ALGORITHMS)
                    self.d.add("E117", f"unknown algorithm '{text}'", s.span,
                               hint=f"did you mean '{sug}'?" if sug else "choose " + ", ".join(ALGORITHMS))
                    errors += 1
                    continue
                out[s.name] = text
                continue
            if isinstance(value, str):
                self.d.add("E117", f"'{s.name}' takes a number, not a string", s.span)
                errors += 1
                continue
            try:
                number = self.constant(value, f"the training setting {s.name}")
            except _Unresolved:
                errors += 1
                continue
            if kind == "int":
                if not float(number).is_integer() or number < 0:
                    self.d.add("E117", f"'{s.name}' must be a whole number, not {_fmt(number)}", s.span)
                    errors += 1
                    continue
                number = int(number)
            out[s.name] = number
        if errors:
            raise _Unresolved
        return out

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


def dependency_order(names: list[str], deps: Callable[[str], Iterable[str]]) -> tuple[list[str], list[str]]:
    """``names`` ordered so that each comes after those it depends on, and the names at which a
    cycle was found. A name on a cycle, or depending on one, is left out of the order. A
    depth-first search with an explicit stack: a chain of definitions may be as long as the file."""
    VISITING, DONE, FAILED = 1, 2, 3
    state: dict[str, int] = {}
    order: list[str] = []
    cyclic: list[str] = []
    for root in names:
        if root in state:
            continue
        state[root] = VISITING
        stack = [(root, iter(deps(root)))]
        failed: set[str] = set()
        while stack:
            name, pending = stack[-1]
            for d in pending:
                seen = state.get(d)
                if seen is None:
                    state[d] = VISITING
                    stack.append((d, iter(deps(d))))
                    break
                if seen == VISITING:  # back to a name being defined: a cycle through it
                    if d not in cyclic:
                        cyclic.append(d)
                    failed.add(name)
                elif seen == FAILED:
                    failed.add(name)
            else:
                stack.pop()
                if name in failed:
                    state[name] = FAILED
                    if stack:
                        failed.add(stack[-1][0])
                else:
                    state[name] = DONE
                    order.append(name)
    return order, cyclic


def _a(word: str) -> str:
    """``word`` with its article: a state, an action."""
    return ("an " if word[:1] in "aeiou" else "a ") + word


def _fmt(x: float) -> str:
    return f"{x:.6g}"


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
