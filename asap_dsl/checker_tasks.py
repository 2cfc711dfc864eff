"""The checks of tasks (clauses, initial boxes, rewards, observation, training settings): a part
of :class:`asap_dsl.checker.Checker`, over its shared state. :func:`reward_model` is also what
checks a reward given on its own (``asapc train --reward``, :func:`asap_dsl.checker.check_reward`)."""

from __future__ import annotations

import math
from typing import Callable, Optional

from . import ast
from .checker_common import (ALGORITHMS, CONST, OBSERVATION_SCALINGS, OBSERVE_ITEMS, REWARDS, RUN_SETTINGS, TRAIN_SETTINGS,
                             CheckState, _Unresolved, setting_problem)
from .checker_exprs import Conditions, Numbers
from .diagnostics import Span
from .diagnostics import closest as _closest
from .formatting import number
from .limits import LIMITS
from .model import RewardModel, TaskModel
from .stl import ir


class TaskChecks:
    """Tasks: each to a :class:`~asap_dsl.model.TaskModel`, or None where it has errors."""

    def __init__(self, state: CheckState, numbers: Numbers, conditions: Conditions):
        self.s, self.n, self.c = state, numbers, conditions
        self.d = state.diag

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

        asap = attempt(self.c.clause_condition, clauses["asap"], "asap") if "asap" in clauses else None
        avoid = attempt(self.c.clause_condition, clauses["avoid"], "avoid") if "avoid" in clauses else None
        deadline = attempt(self.n.positive_steps, clauses["deadline"].value, "the deadline") if "deadline" in clauses else None
        if deadline is not None and deadline > LIMITS.deadline_steps:
            # Every episode, evaluation and oracle horizon is this long: beyond it nothing finishes.
            self.d.add("E117", f"a deadline of {deadline:,} steps is more than {LIMITS.deadline_steps:,}",
                       clauses["deadline"].span, hint="a larger dt makes the same time fewer steps; "
                       "`asapc --max-deadline STEPS` raises the limit")
            errors += 1
            deadline = None
        if deadline is not None and self.s.dt is not None and not math.isfinite(deadline * self.s.dt):
            self.d.add("E117", f"a deadline of {deadline:,} steps of dt = {number(self.s.dt)} s is longer than a float "
                       "holds in seconds", clauses["deadline"].span, hint="give dt in seconds of a physical size")
            errors += 1
            deadline = None
        tolerances: tuple[int, ...] = (deadline,) if deadline else ()
        if "tolerances" in clauses:
            tolerances = tuple(attempt(self.n.positive_steps, d, "a tolerance", default=0) for d in clauses["tolerances"].value)
        episode = (deadline, deadline) if deadline else (1, 1)
        if "episode" in clauses:
            lo_d, hi_d = clauses["episode"].value
            lo = attempt(self.n.positive_steps, lo_d, "the shortest episode")  # None: reported
            hi = attempt(self.n.positive_steps, hi_d, "the longest episode")
            if lo and hi and lo > hi:
                self.d.add("E105", f"the episode range {lo}..{hi} has its lower bound above its upper bound", clauses["episode"].span)
                errors += 1
            episode = (lo or 1, hi or 1)
        reward = attempt(reward_model, clauses["reward"].value, self.n) if "reward" in clauses else RewardModel()
        asap_regions = ir.positive_regions(asap) if asap is not None else ()
        if reward is not None and reward.kind == "distance" and asap is not None and not asap_regions:
            self.d.add("E117", "reward distance(...) measures the distance to the `asap` region, but `asap` names no region",
                       clauses["reward"].span, hint="write `asap in REGION` (possibly with more conditions), or use reward asap or rho")
            errors += 1
        r_sat = None
        if "r_sat" in clauses:
            value = clauses["r_sat"].value
            if not (isinstance(value, ast.Name) and value.id == "auto"):
                r_sat = attempt(self.n.finite_constant, value, "r_sat")
        observe, observe_scaling = ("state",), None
        if "observe" in clauses:
            observe, observe_scaling = attempt(self.observe, clauses["observe"].value, default=(("state",), None))
        train = attempt(self.train, clauses["train"].value, default={}) if "train" in clauses else {}
        init_box = attempt(self.task_init, clauses["init"].value) if "init" in clauses else None
        if errors or asap is None or deadline is None:
            return None
        return TaskModel(
            t.name, asap, avoid, deadline, tolerances, episode, reward or RewardModel(), r_sat, observe, train, t.span,
            {k: c.span for k, c in clauses.items()},
            asap_regions, ir.positive_regions(avoid) if avoid is not None else (), init_box,
            observe_scaling=observe_scaling,
        )

    def task_init(self, box: ast.Box) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """``init box(theta in [a, b], ...)``: the task's initial box, each named state's range
        replacing the system's (the others keep theirs), with the checks of a state's `init`."""
        by_name = {s.name: s for s in self.s.states}
        low = [s.init_low for s in self.s.states]
        high = [s.init_high for s in self.s.states]
        seen: dict[str, Span] = {}
        errors = 0
        if not box.sides:
            self.d.add("E117", "`init box()` names no state", box.span, hint="write init box(x in [a, b], ...)")
            raise _Unresolved
        for side in box.sides:
            if not self.n.state_once(side.var, side.span, by_name, seen, "the task's init box", "E103",
                                     "an initial box is over states",
                                     "E102", "is given twice in the init box (first at line {line})"):
                errors += 1
                continue
            state = by_name[side.var]
            seen[side.var] = side.span
            try:
                lo, hi = self.n.range_(side.bounds, f"the init range of '{side.var}'")
            except _Unresolved:
                errors += 1
                continue
            if lo < state.low or hi > state.high:
                self.d.add("E108", f"the init range [{number(lo)}, {number(hi)}] of '{side.var}' is not inside its state space "
                           f"[{number(state.low)}, {number(state.high)}]", side.bounds.span)
                errors += 1
                continue
            if not (math.isfinite(lo) and math.isfinite(hi) and math.isfinite(hi - lo)):
                self.d.add("E122", f"the init range [{number(lo)}, {number(hi)}] of '{side.var}' cannot be sampled uniformly: "
                           "it must be finite", side.bounds.span)
                errors += 1
                continue
            low[state.index], high[state.index] = lo, hi
        if errors:
            raise _Unresolved
        return tuple(low), tuple(high)

    def observe(self, items) -> tuple[tuple[str, ...], Optional[str]]:
        """The observed items (the state first) and ``scaling = ...`` if given."""
        names: list[str] = []
        scaling: Optional[str] = None
        for item in items:
            if isinstance(item, ast.Setting):
                scaling = self._observe_scaling(item, scaling)
                continue
            name, span = item
            if name not in OBSERVE_ITEMS:
                sug = _closest(name, OBSERVE_ITEMS)
                self.d.add("E117", f"cannot observe '{name}'", span, hint=f"did you mean '{sug}'?" if sug else "observe state or state, time")
                raise _Unresolved
            if name in names:
                self.d.add("E117", f"'{name}' is observed twice", span)
                raise _Unresolved
            names.append(name)
        if not names:  # `observe scaling = none`: the state, scaled so
            names = ["state"]
        if names[0] != "state":
            first = next(item for item in items if not isinstance(item, ast.Setting))
            self.d.add("E117", "the observation starts with the state: write `observe state, time`", first[1])
            raise _Unresolved
        return tuple(names), scaling

    def _observe_scaling(self, s: ast.Setting, earlier: Optional[str]) -> str:
        if s.name != "scaling":
            self.d.add("E117", f"`observe` has no setting '{s.name}'", s.name_span,
                       hint="did you mean 'scaling'?" if _closest(s.name, ("scaling",)) else
                       "write `observe state, scaling = init` (init, state or none)")
            raise _Unresolved
        if earlier is not None:
            self.d.add("E117", "the observation's scaling is given twice", s.span)
            raise _Unresolved
        if s.value not in OBSERVATION_SCALINGS:
            sug = _closest(s.value, OBSERVATION_SCALINGS)
            self.d.add("E117", f"unknown observation scaling '{s.value}'", s.span,
                       hint=(f"did you mean '{sug}'? " if sug else "") + "init (the init box where it has width, else "
                       "the state space), state (the state space where it is bounded, else the init box) or none")
            raise _Unresolved
        return s.value

    def train(self, settings) -> dict:
        """The ``train { ... }`` block: the run's own settings (typed) and the algorithms'
        keywords (:data:`HYPERPARAMETERS`) as values — numbers, true/false, texts, lists and named
        values. Which keywords the run's algorithm and engine take is checked when it trains."""
        out: dict = {}
        errors = 0
        for s in settings:
            if s.name in out:
                self.d.add("E117", f"'{s.name}' is given twice in the train block", s.name_span, hint="keep one")
                errors += 1
                continue
            if s.name not in TRAIN_SETTINGS:
                sug = _closest(s.name, TRAIN_SETTINGS)
                self.d.add("E117", f"unknown training setting '{s.name}'", s.name_span,
                           hint=f"did you mean '{sug}'?" if sug else "the run's settings are " + ", ".join(RUN_SETTINGS)
                           + ", and the algorithm's keywords (learning_rate, use_sde, net_arch, ...)")
                errors += 1
                continue
            try:
                out[s.name] = self._train_setting(s)
            except _Unresolved:
                errors += 1
        if errors:
            raise _Unresolved
        return out

    def _train_setting(self, s: ast.Setting):
        kind = TRAIN_SETTINGS[s.name]
        if kind == "str":
            text = _text(s.value)
            if text is None:
                self.d.add("E117", f"'{s.name}' takes a name, such as `{s.name} = sac`", s.span)
                raise _Unresolved
            if s.name == "algo" and text not in ALGORITHMS:
                sug = _closest(text, ALGORITHMS)
                self.d.add("E117", f"unknown algorithm '{text}'", s.span,
                           hint=f"did you mean '{sug}'?" if sug else "choose " + ", ".join(ALGORITHMS))
                raise _Unresolved
            return text
        value = self._train_value(s.value, f"the training setting {s.name}")
        problem = setting_problem(s.name, value)
        if problem is not None:
            self.d.add("E117", problem, s.span)
            raise _Unresolved
        return value

    def _train_value(self, value, what: str):
        """A training value as Python data: a number (whole numbers as int), a bool, a text (a
        string, or a name that is no constant: `ent_coef = auto`), a list or a dict."""
        if isinstance(value, ast.BoolLiteral):
            return bool(value.value)
        text = _text(value)
        if text is not None and not (isinstance(value, ast.Name) and self.s.kinds.get(value.id, (None,))[0] == CONST):
            return text
        if isinstance(value, ast.ListValue):
            return [self._train_value(v, what) for v in value.items]
        if isinstance(value, ast.ObjectValue):
            out: dict = {}
            for name, v, span in value.entries:
                if name in out:
                    self.d.add("E117", f"'{name}' is given twice in {what}", span)
                    raise _Unresolved
                out[name] = self._train_value(v, what)
            return out
        x = self.n.constant(value, what)
        if not math.isfinite(x):
            self.d.add("E117", f"{what} must be a finite number, not {number(x)}", value.span)
            raise _Unresolved
        return int(x) if float(x).is_integer() and abs(x) < 2 ** 53 else float(x)


def _text(value) -> Optional[str]:
    """The text of a string literal (without its quotes) or of a bare name; None otherwise."""
    if isinstance(value, str):
        return value[1:-1]
    if isinstance(value, ast.Name):
        return value.id
    return None


def reward_model(syn: ast.RewardSyntax, numbers: Numbers) -> RewardModel:
    """The reward ``syn`` names, its settings checked (a window in whole steps, at least one;
    the others finite float32 numbers) and the defaults of :data:`REWARDS` filled in; problems
    go to ``numbers``' diagnostics and raise :class:`_Unresolved`."""
    d = numbers.d
    if syn.kind not in REWARDS:
        sug = _closest(syn.kind, REWARDS)
        d.add("E117", f"unknown reward '{syn.kind}'", syn.span,
              hint=f"did you mean '{sug}'?" if sug else "choose asap, rho, rho(window = D) or distance(...)")
        raise _Unresolved
    takes = REWARDS[syn.kind]
    params: dict[str, float] = {}
    for s in syn.settings:
        if s.name in params:
            d.add("E117", f"reward {syn.kind} is given '{s.name}' twice", s.name_span, hint="keep one")
            raise _Unresolved
        if s.name not in takes:
            d.add("E117", f"reward {syn.kind} has no setting '{s.name}'", s.name_span,
                  hint=f"it takes {', '.join(takes) or 'no settings'}")
            raise _Unresolved
        if s.name == "window":
            params["window"] = _window(s, numbers)
        else:
            params[s.name] = numbers.finite_constant(s.value, f"the reward setting {s.name}")
    defaults = {k: v for k, v in takes.items() if v is not None}
    return RewardModel(syn.kind, {**defaults, **params}, syn.span)


def _window(s: ast.Setting, numbers: Numbers) -> int:
    if isinstance(s.value, ast.Duration):  # rho(window = 1s)
        return numbers.positive_steps(s.value, "the reward window")
    if isinstance(s.value, ast.Number):
        return numbers.positive_steps(ast.Duration(s.value.value, "steps", s.value.span), "the reward window")
    window = numbers.constant(s.value, "the reward window")
    if not float(window).is_integer() or window < 1:
        numbers.d.add("E117", "the reward window must be a whole number of steps, at least 1", s.span)
        raise _Unresolved
    return int(window)
