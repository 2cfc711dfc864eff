"""The checks of the system (constants, dt, states, actions, lets, dynamics, integrator) and of
the regions: a part of :class:`asap_dsl.checker.Checker`, over its shared state."""

from __future__ import annotations

import math
from typing import Optional

from . import ast
from .checker_common import (ACTION, CONST, FORMULA, INTEGRATORS, LET, REGION, STATE, SYSTEM, TASK, CheckState, _a,
                             _Unresolved, dependency_order)
from .checker_exprs import ACTION_LET_HINT, Numbers
from .diagnostics import Span
from .diagnostics import closest as _closest
from .expr import compile_batched, names_in
from .formatting import number
from .limits import LIMITS
from .model import ActionVar, Integrator, RegionModel, StateVar, SystemModel
from .rewards import FLOAT32_MAX


class SystemChecks:
    """The system and its regions: fills the state's constants, dt, states, actions, lets and
    regions, and declares every name of the module."""

    def __init__(self, state: CheckState, numbers: Numbers):
        self.s, self.n = state, numbers
        self.d = state.diag

    def check_system(self) -> Optional[SystemModel]:
        if not self.s.module.systems:
            self.d.add("E114", "the file declares no system", Span(1, 1, 1, 2),
                       hint="a spec starts with `system NAME { state ..., action ..., dt = ..., ode { ... } }`")
            return None
        for extra in self.s.module.systems[1:]:
            self.d.add("E119", f"a file holds one system; '{extra.name}' is a second one", extra.name_span)
        sys = self.s.module.systems[0]
        self.n.declare(sys.name, SYSTEM, sys.name_span)
        # Declare every name first so that uses can say what a name is even out of order.
        for c in sys.consts:
            self.n.declare(c.name, CONST, c.name_span)
        for s in sys.states:
            self.n.declare(s.name, STATE, s.name_span)
        for a in sys.actions:
            self.n.declare(a.name, ACTION, a.name_span)
        for lt in sys.lets:
            self.n.declare(lt.name, LET, lt.name_span)

        is_map = bool(sys.dynamics) and isinstance(sys.dynamics[0], ast.Dynamics) and sys.dynamics[0].kind == "map"
        if not sys.dt and is_map:
            self.s.steps_only = True  # a map needs no step length: its spec counts in steps
        elif not sys.dt:
            self.d.add("E114", f"system '{sys.name}' has no `dt = ...` (seconds per step)", sys.name_span)
        for extra in sys.dt[1:]:
            self.d.add("E119", "dt is given more than once", extra.span)
        # `dt = ...` is a constant like the others, read as `dt` by any expression: in order with the
        # constants (a constant may use those before it, dt included).
        steps: list = [(c.span.line, c.span.column, c) for c in sys.consts]
        if sys.dt:
            self.n.declare("dt", CONST, sys.dt[0].span)
            self.s.used.add("dt")  # never reported unused: it is the system's step
            steps.append((sys.dt[0].span.line, sys.dt[0].span.column, sys.dt[0]))
        for _, _, c in sorted(steps, key=lambda item: item[:2]):
            if not isinstance(c, ast.ConstDecl):
                self.check_dt(c)
                continue
            if not self.s.declared_here(c.name, c.name_span):
                continue
            try:
                self.s.consts[c.name] = self.n.constant(c.value, f"constant '{c.name}'")
            except _Unresolved:
                self.s.const_failed.add(c.name)

        for s in sys.states:
            if not self.s.declared_here(s.name, s.name_span):
                continue
            try:
                lo, hi = self.n.range_(s.space, f"the state space of '{s.name}'")
                if not lo < hi:
                    self.d.add("E117", f"the state space of '{s.name}' is empty or a single point", s.space.span)
                    raise _Unresolved
                ilo, ihi = (lo, hi) if s.init is None else self.n.range_(s.init, f"the init range of '{s.name}'")
            except _Unresolved:
                lo, hi, ilo, ihi = -math.inf, math.inf, 0.0, 0.0
            self.s.states.append(StateVar(s.name, len(self.s.states), lo, hi, ilo, ihi, s.span, s.init.span if s.init else None))
        if not sys.states:
            self.d.add("E114", f"system '{sys.name}' declares no state", sys.name_span)

        for a in sys.actions:
            if not self.s.declared_here(a.name, a.name_span):
                continue
            try:
                lo, hi = self.n.range_(a.bounds, f"the bounds of action '{a.name}'")
                if not (math.isfinite(lo) and math.isfinite(hi)):
                    self.d.add("E117", f"the bounds of action '{a.name}' must be finite", a.bounds.span)
                elif not (abs(lo) <= FLOAT32_MAX and abs(hi) <= FLOAT32_MAX):  # beyond, the action space is ±inf
                    self.d.add("E117", f"the bounds of action '{a.name}' must lie within ±3.4e38: an agent's actions "
                               f"are float32, and [{number(lo)}, {number(hi)}] is not", a.bounds.span)
            except _Unresolved:
                lo, hi = -1.0, 1.0
            self.s.actions.append(ActionVar(a.name, len(self.s.actions), lo, hi, a.span))

        # Lets: over states, actions, constants and other lets (any order, no cycles). A let that
        # reads an action (itself or through another let) is known only where the actions are.
        let_decls = {lt.name: lt for lt in sys.lets if self.s.declared_here(lt.name, lt.name_span)}
        order = self._let_order(let_decls)
        action_names = {a.name for a in self.s.actions}
        for name in order:
            lt = let_decls[name]
            try:
                self.n.number(lt.value, (CONST, STATE, ACTION, LET), f"let '{name}'")
                self.s.lets[name] = lt.value
            except _Unresolved:
                continue
            read = next((m.id if m.id in action_names else self.s.action_lets[m.id] for m in names_in(lt.value)
                         if m.id in action_names or m.id in self.s.action_lets), None)
            if read is not None:
                self.s.action_lets[name] = read
        for name in self.s.lets:
            self.n.check_domains([self.s.lets[name]], f"let '{name}'", actions=name in self.s.action_lets)

        kind, equations, simulator, dyn_span = self.check_dynamics(sys)
        integrator = self.check_integrator(sys, kind)
        if equations:
            self.n.check_domains(equations, "the dynamics", actions=True)
        if (self.s.dt is None and not self.s.steps_only) or kind is None:
            return None
        return SystemModel(sys.name, tuple(self.s.states), tuple(self.s.actions), dict(self.s.consts), dict(self.s.lets),
                           self.s.dt, kind, equations, simulator, integrator, sys.span, dyn_span)

    def check_dt(self, e: ast.Expr) -> None:
        try:
            dt = self.n.constant(e, "dt")
        except _Unresolved:
            self.s.const_failed.add("dt")
            return
        if not dt > 0 or not math.isfinite(dt):
            self.d.add("E117", f"dt must be a positive number of seconds, not {number(dt)}", e.span)
            self.s.const_failed.add("dt")
            return
        self.s.dt = dt
        self.s.consts["dt"] = dt

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
        state_names = [s.name for s in self.s.states]
        given: dict[str, ast.Equation] = {}
        first: dict[str, Span] = {}
        errors = 0
        prime = "'" if dyn.kind == "ode" else ""
        known = dict.fromkeys(state_names)  # looked up once per equation: hashed, or 20,000 states cost seconds
        for eq in dyn.equations:
            if not self.n.state_once(eq.target, eq.target_span, known, first, dyn.kind, "E110",
                                     f"{dyn.kind} equations are for states",
                                     "E110", "has a second equation (the first is at line {line})"):
                errors += 1
                continue
            given[eq.target], first[eq.target] = eq, eq.span
            try:
                self.n.number(eq.value, (CONST, STATE, ACTION, LET), f"the {dyn.kind} equation of '{eq.target}'")
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
                v = self.n.constant(s.value, "substeps")
            except _Unresolved:
                continue
            if not float(v).is_integer() or v < 1:
                self.d.add("E117", "substeps must be a whole number of at least 1", s.span)
                continue
            if v > LIMITS.substeps:  # every step of every environment would take that many evaluations
                self.d.add("E117", f"substeps = {number(v)} is more than {LIMITS.substeps:,}", s.span,
                           hint="a few substeps integrate as accurately at a fraction of the cost; "
                           "`asapc --max-substeps N` raises the limit")
                continue
            substeps = int(v)
        return Integrator(decl.method, substeps if decl.method != "exact" else 1, decl.span)

    def check_regions(self) -> None:
        for r in self.s.module.regions:
            self.n.declare(r.name, REGION, r.name_span)
        for f in self.s.module.formulas:
            self.n.declare(f.name, FORMULA, f.name_span)
        for t in self.s.module.tasks:
            self.n.declare(t.name, TASK, t.name_span)
        state_names = [s.name for s in self.s.states]
        symbols = self.n.symbols()
        for r in self.s.module.regions:
            if not self.s.declared_here(r.name, r.name_span):
                continue
            try:
                model = self.region(r, state_names)
            except _Unresolved:
                continue
            values = compile_batched([ast.Name(c, Span()) for c in model.coords], symbols)
            self.s.regions[r.name] = RegionModel(model.name, model.kind, model.coords, model.centre, model.radius,
                                               model.low, model.high, r.span, values)

    def coordinate(self, name: str, span: Span, coords: list[str], twice: str) -> None:
        """Check that ``name`` can be a coordinate of a region (a state or a let) and is not one of
        ``coords`` already (``twice`` says so); raises :class:`_Unresolved` if not."""
        if name in coords:
            self.d.add("E102", twice, span)
            raise _Unresolved
        kind = self.s.kinds.get(name, (None,))[0]
        if kind in (STATE, LET):
            if kind == LET and name not in self.s.lets:
                raise _Unresolved
            if name in self.s.action_lets:
                self.d.add("E103", f"'{name}' is a let that reads the action '{self.s.action_lets[name]}'; a region "
                           "is over states and lets of states", span, hint=ACTION_LET_HINT)
                raise _Unresolved
            self.s.used.add(name)
            return
        if kind is None:
            self.n.unknown(name, span, (STATE, LET))
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
                    try:
                        self.coordinate(c.name, c.span, coords, f"'{c.name}' appears twice in the centre of region '{r.name}'")
                        coords.append(c.name)
                        centre.append(self.n.constant(c.value, "a ball centre"))
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
                        centre.append(self.n.constant(c, "a ball centre"))
                    except _Unresolved:
                        errors += 1
                coords = list(state_names)
            try:
                radius = self.n.constant(shape.radius, "a ball radius")
                if not radius > 0:
                    self.d.add("E117", f"the radius of region '{r.name}' must be positive, not {number(radius)}", shape.radius.span)
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
            try:
                self.coordinate(side.var, side.span, coords, f"'{side.var}' is bounded twice in box '{r.name}'")
                lo, hi = self.n.range_(side.bounds, f"the side '{side.var}' of box '{r.name}'")
                coords.append(side.var)
                lows.append(lo)
                highs.append(hi)
            except _Unresolved:
                errors += 1
        if errors:
            raise _Unresolved
        return RegionModel(r.name, "box", tuple(coords), low=tuple(lows), high=tuple(highs))
