"""Lint rules over the checked model: small classes, one stable code each.

The checker reports what prevents compiling (names, types, units, causality). These rules look
at a program that compiled and judge whether it means what its author likely wants. Each rule is
a subclass of :class:`LintRule` registered in :data:`LINT_RULES`; its ``code`` is listed in
:data:`asap_dsl.diagnostics.RULES` and documented in ``docs/language.md``. One check is not a
rule: :func:`deadline_checks` (W208, ``asapc lint --deep``) samples states and runs the oracle,
so it is asked for, not run with every compile.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, ClassVar, Optional

import numpy as np

from .diagnostics import Collector, Diagnostic, make
from .expr import degree
from .formatting import number
from .model import ProgramModel, RegionModel, TaskModel
from .stl import ir

if TYPE_CHECKING:  # program imports this module
    from .program import Program


class LintRule:
    """A rule: ``check`` reports into the collector (it may report several times)."""

    code: ClassVar[str]

    def check(self, prog: ProgramModel, out: Collector) -> None:  # pragma: no cover - interface
        raise NotImplementedError


LINT_RULES: list[type[LintRule]] = []


def rule(cls: type[LintRule]) -> type[LintRule]:
    LINT_RULES.append(cls)
    return cls


@rule
class InitOutsideSpace(LintRule):
    code = "E108"

    def check(self, prog, out):
        for s in prog.system.states:
            if s.init_span is not None and (s.init_low < s.low or s.init_high > s.high):
                out.add(self.code, f"the init range [{s.init_low:g}, {s.init_high:g}] of '{s.name}' is not inside its state "
                        f"space [{s.low:g}, {s.high:g}]", s.init_span)


@rule
class InitNotSampleable(LintRule):
    """Initial states are drawn uniformly from the init box: each side must be finite and its
    width too (``uniform(-1e308, 1e308)`` overflows)."""

    code = "E122"

    def check(self, prog, out):
        for s in prog.system.states:
            lo, hi = s.init_low, s.init_high
            if math.isfinite(lo) and math.isfinite(hi) and math.isfinite(hi - lo):
                continue
            if s.init_span is None:
                out.add(self.code, f"initial states of '{s.name}' are drawn from its state space [{lo:g}, {hi:g}], "
                        "which is not a finite range", s.span,
                        hint=f"give '{s.name}' a finite init range: `state {s.name} in [...] init [lo, hi]`")
            else:
                out.add(self.code, f"the init range [{lo:g}, {hi:g}] of '{s.name}' cannot be sampled uniformly "
                        "(it is infinite, or its width overflows)", s.init_span, hint="give a finite init range")


@rule
class TaskNeedsAction(LintRule):
    """A task is something to control: without an action there is no policy to train or oracle
    to solve (a spec of formulas only, to monitor traces, needs none)."""

    code = "E114"

    def check(self, prog, out):
        if prog.tasks and not prog.system.actions:
            first = next(iter(prog.tasks.values()))
            out.add(self.code, f"system '{prog.system.name}' declares no action, so task '{first.name}' has nothing "
                    "to control", prog.system.span, hint="declare one: `action u in [lo, hi]`")


@rule
class InitInsideAvoid(LintRule):
    """Episodes start from states drawn in the init box and redrawn while ``avoid`` holds: if it
    holds on all of a sample of the box, no episode can start (training, evaluation, the oracle)."""

    code = "E123"
    SAMPLES = 512

    def check(self, prog, out):
        from .stl import offline

        from .sampling import init_box

        sys_ = prog.system
        for t in prog.tasks.values():
            if t.avoid is None:
                continue
            lo, hi = init_box(sys_, t.init_box)  # the task's own box, if it has one
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(np.isfinite(hi - lo))):
                continue  # E122 says so
            states = np.random.default_rng(0).uniform(lo, hi, size=(self.SAMPLES, sys_.n_state))
            if offline.satisfied(t.avoid, states[:, None, :])[:, 0].all():
                out.add(self.code, f"`avoid` of task '{t.name}' holds at every one of {self.SAMPLES} initial states "
                        "drawn from the init box: no episode can start", t.clause_spans["avoid"],
                        hint="shrink the init box, or the regions of `avoid`")


@rule
class ExactNeedsLinear(LintRule):
    code = "E111"

    def check(self, prog, out):
        sys = prog.system
        if sys.kind != "ode" or sys.integrator.method != "exact":
            return
        for s, rhs in zip(sys.states, sys.equations):
            if degree(rhs, sys.symbols) > 1:
                out.add(self.code, f"`integrator exact` needs linear dynamics, but the equation of '{s.name}' is not linear "
                        "in states and actions", sys.integrator.span or sys.dynamics_span,
                        hint="use `integrator rk4(substeps = 4)` for non-linear dynamics")
                return


@rule
class ExactStepOverflows(LintRule):
    code = "E124"  # the step is NaN or infinite for every state, as an operation outside its domain

    def check(self, prog, out):
        from .dynamics import zero_order_hold

        sys = prog.system
        if sys.kind != "ode" or sys.integrator.method != "exact" or any(
                degree(rhs, sys.symbols) > 1 for rhs in sys.equations):
            return
        if not all(np.all(np.isfinite(part)) for part in zero_order_hold(sys)):
            out.add(self.code, f"`integrator exact`: the exact step over dt = {number(sys.dt)} (the matrix exponential "
                    "of the dynamics) overflows a float: the next state is NaN or infinite for every state",
                    sys.integrator.span or sys.dynamics_span,
                    hint="use a smaller dt, or check the dynamics' coefficients")


@rule
class ToleranceAboveDeadline(LintRule):
    code = "E112"

    def check(self, prog, out):
        for t in prog.tasks.values():
            for tol in t.tolerances:
                if tol > t.deadline:
                    out.add(self.code, f"tolerance {tol} of task '{t.name}' is above its deadline {t.deadline}",
                            t.clause_spans.get("tolerances", t.span), hint="evaluation never runs past the deadline")
            if t.episode[1] > t.deadline:
                out.add(self.code, f"the longest episode ({t.episode[1]} steps) of task '{t.name}' is above its deadline "
                        f"{t.deadline}", t.clause_spans.get("episode", t.span),
                        hint="the deadline is the longest training episode")


def _goal_regions(prog: ProgramModel, t: TaskModel) -> list[RegionModel]:
    return [prog.regions[r] for r in t.asap_regions if r in prog.regions]


def _region_box_gap(region: RegionModel, prog: ProgramModel) -> Optional[tuple[float, float]]:
    """(distance from the state space to the region, share of the region's extent inside), states only."""
    idx = {s.name: s for s in prog.system.states}
    if not all(c in idx for c in region.coords):
        return None
    lo = np.array([idx[c].low for c in region.coords])
    hi = np.array([idx[c].high for c in region.coords])
    if region.kind == "ball":
        c = np.asarray(region.centre)
        gap = float(np.linalg.norm(np.maximum(lo - c, 0) + np.maximum(c - hi, 0)))
        inside = bool(np.all(c - region.radius >= lo) and np.all(c + region.radius <= hi))
        return gap - region.radius, 1.0 if inside else 0.0
    rlo, rhi = np.asarray(region.low), np.asarray(region.high)
    gap_vec = np.maximum(lo - rhi, 0) + np.maximum(rlo - hi, 0)
    inside = bool(np.all(rlo >= lo) and np.all(rhi <= hi))
    return float(np.linalg.norm(gap_vec)) if np.any(gap_vec > 0) else -1.0, 1.0 if inside else 0.0


@rule
class GoalOutsideSpace(LintRule):
    """E113 when the goal region cannot meet the state space; W206 when part of it lies outside."""

    code = "E113"

    def check(self, prog, out):
        for t in prog.tasks.values():
            for region in _goal_regions(prog, t):
                gap = _region_box_gap(region, prog)
                if gap is None:
                    continue
                distance, inside = gap
                if distance > 0:
                    out.add("E113", f"region '{region.name}' of task '{t.name}' lies outside the state space: the goal is "
                            "unreachable", t.clause_spans["asap"])
                elif inside < 1.0:
                    out.add("W206", f"part of region '{region.name}' of task '{t.name}' lies outside the state space",
                            t.clause_spans["asap"], hint="those goal states end the episode as out of bounds")


def _box_over(box: RegionModel, coords: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """A box's sides over ``coords``; a coordinate it does not name is free (-inf, inf)."""
    lo = np.array([box.low[box.coords.index(c)] if c in box.coords else -np.inf for c in coords])
    hi = np.array([box.high[box.coords.index(c)] if c in box.coords else np.inf for c in coords])
    return lo, hi


def regions_overlap(a: RegionModel, b: RegionModel) -> Optional[bool]:
    """Whether two regions share a point; None when it cannot be decided here (two balls over
    different coordinates, or a box naming a coordinate its ball does not)."""
    if a.kind == "box" and b.kind == "box":  # free coordinates always meet
        order = sorted(set(a.coords) | set(b.coords))
        (alo, ahi), (blo, bhi) = _box_over(a, order), _box_over(b, order)
        return bool(np.all(alo <= bhi) and np.all(blo <= ahi))
    if a.kind == "ball" and b.kind == "ball":
        if set(a.coords) != set(b.coords):
            return None
        other = np.array([b.centre[b.coords.index(c)] for c in a.coords])
        return float(np.linalg.norm(np.asarray(a.centre) - other)) <= a.radius + b.radius
    ball, box = (a, b) if a.kind == "ball" else (b, a)
    if not set(box.coords) <= set(ball.coords):
        return None
    c = np.asarray(ball.centre, dtype=float)
    lo, hi = _box_over(box, list(ball.coords))
    return float(np.linalg.norm(c - np.clip(c, lo, hi))) <= ball.radius


@rule
class RegionsOverlap(LintRule):
    code = "W201"

    def check(self, prog, out):
        for t in prog.tasks.values():
            for name in t.avoid_regions:
                if name not in prog.regions:
                    continue
                for g in _regions_meeting(prog, t.asap, prog.regions[name]):
                    out.add(self.code, f"the asap region '{g}' overlaps the avoid region '{name}' in task '{t.name}': "
                            "the target is partly unsafe", t.clause_spans.get("avoid", t.span))


def _regions_meeting(prog: ProgramModel, asap, avoid: RegionModel) -> list[str]:
    """The regions `asap` asks to be in that overlap ``avoid``, leaving out each `or` branch that
    also asks to be in a region disjoint from it (`in hover and in level`, with `level` a box over
    the attitude only: its target is the intersection, which may lie well away from ``avoid``)."""
    if asap is None:
        return []
    out: dict[str, None] = {}
    for branch in ir.operands(asap) if isinstance(asap, ir.Or) else [asap]:
        conjuncts = ir.operands(branch) if isinstance(branch, ir.And) else [branch]
        if any(isinstance(c, ir.Atom) and c.region in prog.regions
               and regions_overlap(prog.regions[c.region], avoid) is False for c in conjuncts):
            continue
        for r in ir.positive_regions(branch):
            if r in prog.regions and regions_overlap(prog.regions[r], avoid):
                out.setdefault(r)
    return list(out)


@rule
class AsapNeverHolds(LintRule):
    """`asap in goal and in wall` with disjoint regions: no state is in both, so no episode can
    ever fulfil the task (each `or` branch is judged; regions over different coordinates, whose
    overlap is not decided, never fire it)."""

    code = "E125"

    def check(self, prog, out):
        for t in prog.tasks.values():
            pairs = []
            for branch in ir.operands(t.asap) if isinstance(t.asap, ir.Or) else [t.asap]:
                pair = _disjoint_pair(prog, ir.operands(branch) if isinstance(branch, ir.And) else [branch])
                if pair is None:
                    break
                pairs.append(pair)
            else:
                a, b = pairs[0]
                more = " (and so does every other branch of its `or`)" if len(pairs) > 1 else ""
                out.add(self.code, f"`asap` of task '{t.name}' can never hold: it asks to be in regions '{a}' and '{b}' "
                        f"at once, and they do not overlap{more}", t.clause_spans["asap"],
                        hint="did you mean `or`, or `and not in ...`?")


def _disjoint_pair(prog: ProgramModel, conjuncts: list) -> Optional[tuple[str, str]]:
    regions = [c.region for c in conjuncts if isinstance(c, ir.Atom) and c.region in prog.regions]
    for i, a in enumerate(regions):
        for b in regions[i + 1:]:
            if regions_overlap(prog.regions[a], prog.regions[b]) is False:
                return a, b
    return None


@rule
class UnusedName(LintRule):
    code = "W202"

    def check(self, prog, out):
        for name, (kind, span) in prog.declared.items():
            if kind in ("constant", "let", "region", "formula") and name not in prog.used:
                out.add(self.code, f"{kind} '{name}' is never used", span)


@rule
class HorizonBeyondDeadline(LintRule):
    code = "W203"

    def check(self, prog, out):
        for t in prog.tasks.values():
            for clause, node in (("asap", t.asap), ("avoid", t.avoid)):
                if node is None:
                    continue
                past = ir.history(node)
                if past > t.deadline:
                    shown = "unbounded" if math.isinf(past) else f"{past:g} steps"
                    if math.isinf(past):
                        continue  # [0, inf] past windows are the usual "ever since the start"
                    out.add(self.code, f"`{clause}` of task '{t.name}' looks {shown} into the past, beyond the deadline "
                            f"of {t.deadline} steps", t.clause_spans[clause],
                            hint="no episode is that long: the window is always cut")


@rule
class RSatBelowBound(LintRule):
    code = "W204"

    def check(self, prog, out):
        for t in prog.tasks.values():
            if t.r_sat is None:
                continue
            bound = t.r_sat_bound
            if math.isfinite(bound) and t.r_sat <= bound:
                out.add(self.code, f"r_sat = {t.r_sat:g} of task '{t.name}' is not above the theorem's bound "
                        f"rho_max + (rho_max - rho_min) * k_max = {number(bound)}", t.clause_spans["r_sat"],
                        hint="an optimal policy may then not be as-soon-as-possible; `r_sat auto` derives a safe value")


@rule
class UnboundedRobustness(LintRule):
    code = "W207"

    def check(self, prog, out):
        for t in prog.tasks.values():
            if t.r_sat is not None or t.reward.kind != "asap":
                continue
            lo, hi = t.rho_bounds
            if not (math.isfinite(lo) and math.isfinite(hi)):
                out.add(self.code, f"the robustness of `asap` in task '{t.name}' has no finite bounds over the state space "
                        f"([{lo:g}, {hi:g}]), so `r_sat auto` cannot apply the theorem", t.clause_spans["asap"],
                        hint="bound the state space, or give a numeric r_sat")


def lint(prog: ProgramModel, out: Collector, rules: Optional[list[type[LintRule]]] = None) -> None:
    """Run every lint rule (or the given ones) on a checked program.

    Geometry with extreme numbers (a centre at 1e308) overflows to inf, which the rules read as
    "far" or "unbounded"; numpy's warnings about it are not the user's business."""
    with np.errstate(all="ignore"):
        for cls in rules or LINT_RULES:
            cls().check(prog, out)


def deadline_checks(prog: Program, samples: int = 16, seconds: float = 60.0,
                    seed: int = 0) -> tuple[list[Diagnostic], list[tuple[str, str]]]:
    """W208 (``asapc lint --deep``): sample ``samples`` initial states of each task and ask the
    oracle whether ``asap`` can hold within the deadline from each, in ``seconds`` of search per
    task shared by its samples (``seed`` draws the states).

    Returns the warnings (at most two per task: the states shown not to make it, and those the
    search could not decide in time) and the tasks it could not check, each with the reason (a
    black-box system, a goal the oracle cannot express)."""
    if prog.system.kind == "simulator":
        why = f"system {prog.system.name} is a black-box simulator: the oracle needs known dynamics (ode or map)"
        return [], [(name, why) for name in prog.tasks]
    from .backends.oracle.solver import deadline_infeasible  # CasADi: only when asked

    out, skipped = [], []
    for name in prog.tasks:
        task = prog.model.tasks[name]
        try:
            bad = deadline_infeasible(prog, name, samples=samples, seed=seed, seconds=seconds)
        except ValueError as err:  # a goal the oracle cannot express: say so
            skipped.append((name, str(err)))
            continue
        decided = [b for b in bad if b[1] != "timeout"]
        undecided = [b for b in bad if b[1] == "timeout"]
        # A search that ran out of time proved nothing: its hint is more time, not another spec.
        more = max(4 * seconds, 60.0)
        for group, says, hint in (
                (decided, "cannot fulfil", "enlarge the deadline or the action bounds, or shrink the init box"),
                (undecided, "were not shown to fulfil",
                 f"the search ran out of its {seconds:g} s for the task before deciding: give it more with "
                 f"`asapc lint --deep --deep-seconds {more:g}`, or run `asapc oracle` on the spec")):
            if not group:
                continue
            state, _, reason = group[0]
            shown = ", ".join(f"{n}={v:.3g}" for n, v in zip(prog.system.state_names, state))
            out.append(make("W208", f"{len(group)} of {samples} sampled initial states of task '{name}' {says} "
                            f"`asap` within the deadline of {task.deadline:,} steps, e.g. from {shown} ({reason})",
                            task.clause_spans["deadline"], prog.file, hint=hint))
    return out, skipped


__all__ = ["LintRule", "LINT_RULES", "deadline_checks", "lint", "regions_overlap"]
