"""The checked program: every name resolved, every constant folded, every time in steps.

The checker (:mod:`asap_dsl.checker`) builds these from the AST; lint rules, evaluators,
simulators, environments and the oracle read them. They hold no source text beyond spans, and
compile their expressions once, on first use.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional

import numpy as np

from . import ast
from .diagnostics import Span
from .expr import SCALAR, ScalarForm, Symbols, compile_batched, compile_function
from .formatting import number
from .stl import ir


@dataclass(frozen=True)
class StateVar:
    name: str
    index: int
    low: float
    high: float
    init_low: float
    init_high: float
    span: Span
    init_span: Optional[Span]


@dataclass(frozen=True)
class ActionVar:
    name: str
    index: int
    low: float
    high: float
    span: Span


@dataclass(frozen=True)
class Integrator:
    """``rk4`` or ``euler`` with ``substeps`` per step, or ``exact`` (zero-order hold)."""

    method: str = "rk4"
    substeps: int = 4
    span: Optional[Span] = None


@dataclass(frozen=True)
class SystemModel:
    name: str
    states: tuple[StateVar, ...]
    actions: tuple[ActionVar, ...]
    consts: Mapping[str, float]
    lets: Mapping[str, ast.Expr]
    dt: Optional[float]  # seconds per step; None: a map without `dt`, whose spec counts in steps only
    kind: str  # "ode", "map" or "simulator"
    equations: tuple[ast.Expr, ...]  # right-hand sides in state order (ode/map)
    simulator: Optional[str]
    integrator: Integrator
    span: Span
    dynamics_span: Span

    @property
    def state_names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.states)

    @property
    def action_names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.actions)

    @property
    def n_state(self) -> int:
        return len(self.states)

    @property
    def n_action(self) -> int:
        return len(self.actions)

    @property
    def state_low(self) -> np.ndarray:
        return np.array([s.low for s in self.states])

    @property
    def state_high(self) -> np.ndarray:
        return np.array([s.high for s in self.states])

    @property
    def init_low(self) -> np.ndarray:
        return np.array([s.init_low for s in self.states])

    @property
    def init_high(self) -> np.ndarray:
        return np.array([s.init_high for s in self.states])

    @property
    def action_low(self) -> np.ndarray:
        return np.array([a.low for a in self.actions])

    @property
    def action_high(self) -> np.ndarray:
        return np.array([a.high for a in self.actions])

    @functools.cached_property
    def symbols(self) -> Symbols:
        return Symbols(
            dict(self.consts),
            {s.name: s.index for s in self.states},
            {a.name: a.index for a in self.actions},
            dict(self.lets),
        )

    @functools.cached_property
    def rhs(self):
        """``f(states [B, n], actions [B, m]) -> [B, n]``: the ODE's derivative or the map's next state."""
        if self.kind == "simulator":
            raise TypeError(f"system {self.name} is a black-box simulator: it has no equations")
        return compile_batched(self.equations, self.symbols)


@dataclass(frozen=True)
class RegionModel:
    """A ball or a box over some variables (states or lets), with its robustness."""

    name: str
    kind: str  # "ball" or "box"
    coords: tuple[str, ...]
    centre: tuple[float, ...] = ()
    radius: float = 0.0
    low: tuple[float, ...] = ()
    high: tuple[float, ...] = ()
    span: Span = field(default=Span(), compare=False)
    # Compiled ``[..., n_state] -> [..., len(coords)]`` (set by the checker).
    values: Any = field(default=None, compare=False, repr=False)

    def robustness(self, states: np.ndarray) -> np.ndarray:
        """Ball: ``r - |x - c|``; box: the smallest signed distance inside over its sides."""
        v = self.values(states)
        if self.kind == "ball":
            return self.radius - np.sqrt(np.sum(np.square(v - np.asarray(self.centre)), axis=-1))
        lo, hi = np.asarray(self.low), np.asarray(self.high)
        return np.min(np.minimum(v - lo, hi - v), axis=-1)

    def satisfied(self, states: np.ndarray) -> np.ndarray:
        v = self.values(states)
        if self.kind == "ball":
            return np.sum(np.square(v - np.asarray(self.centre)), axis=-1) <= self.radius ** 2
        return np.all((v >= np.asarray(self.low)) & (v <= np.asarray(self.high)), axis=-1)

    def distance(self, states: np.ndarray) -> np.ndarray:
        """Euclidean distance from the region (0 inside), over the region's coordinates."""
        v = self.values(states)
        if self.kind == "ball":
            return np.maximum(0.0, np.sqrt(np.sum(np.square(v - np.asarray(self.centre)), axis=-1)) - self.radius)
        gap = np.maximum(np.asarray(self.low) - v, 0.0) + np.maximum(v - np.asarray(self.high), 0.0)
        return np.sqrt(np.sum(np.square(gap), axis=-1))

    def scalar_form(self, symbols):
        """``row -> (robustness, satisfied)`` for one state of Python floats (the batch-1 monitor),
        the same operations as :meth:`robustness` and :meth:`satisfied`."""
        def fallback(row):
            s = np.asarray(row, dtype=np.float64)[None]
            with np.errstate(all="ignore"):
                return float(self.robustness(s)[0]), bool(self.satisfied(s)[0])

        def build():
            values = compile_function([ast.Name(c, Span()) for c in self.coords], symbols, SCALAR)
            if self.kind == "ball":
                centre, r = tuple(self.centre), self.radius

                def ball(row):
                    d2 = 0.0
                    for v, c in zip(values(row, ()), centre):
                        d2 += (v - c) * (v - c)
                    return r - math.sqrt(d2), d2 <= r * r
                return ball
            sides = tuple(zip(self.low, self.high))

            def box(row):
                vs = values(row, ())
                return min(min(v - lo, hi - v) for v, (lo, hi) in zip(vs, sides)), all(lo <= v <= hi for v, (lo, hi) in zip(vs, sides))
            return box
        return ScalarForm(build, fallback)

    def describe(self) -> str:
        if self.kind == "ball":
            centre = ", ".join(f"{n}: {number(c)}" for n, c in zip(self.coords, self.centre))
            return f"ball({{{centre}}}, {number(self.radius)})"
        sides = ", ".join(f"{n} in [{number(a)}, {number(b)}]" for n, a, b in zip(self.coords, self.low, self.high))
        return f"box({sides})"


@dataclass(frozen=True)
class FormulaModel:
    name: str
    ir: ir.Formula
    span: Span


@dataclass(frozen=True)
class RewardModel:
    """``kind`` in ``asap``, ``rho``, ``distance``; ``params`` as given (window in steps)."""

    kind: str = "asap"
    params: Mapping[str, float] = field(default_factory=dict)
    span: Optional[Span] = None

    @property
    def text(self) -> str:
        """As written in a spec: ``asap``, ``rho(window = 5)``, ``distance(lambda_t = 1, ...)``."""
        if not self.params:
            return self.kind
        return self.kind + "(" + ", ".join(f"{k} = {number(v)}" for k, v in self.params.items()) + ")"


@dataclass(frozen=True)
class TaskModel:
    name: str
    asap: ir.Formula
    avoid: Optional[ir.Formula]
    deadline: int
    tolerances: tuple[int, ...]
    episode: tuple[int, int]
    reward: RewardModel
    r_sat: Optional[float]  # None: auto
    observe: tuple[str, ...]
    train: Mapping[str, Any]
    span: Span
    clause_spans: Mapping[str, Span]
    asap_regions: tuple[str, ...]  # regions of `in R` atoms occurring positively in asap / avoid
    avoid_regions: tuple[str, ...]
    # The task's own initial box (`init box(...)`), every state's range, those it does not name
    # from the system's `init`; None: the system's box.
    init_box: Optional[tuple[tuple[float, ...], tuple[float, ...]]] = None
    # `observe scaling = init | state | none`: how training scales the policy's inputs
    # (asap_dsl.observation); None: the training preset's choice.
    observe_scaling: Optional[str] = None

    @property
    def spec(self) -> ir.Formula:
        """``eventually[0, D] asap and always[0, D] not avoid`` — what evaluation checks."""
        window = ir.Interval(0, self.deadline)
        reach = ir.Eventually(window, self.asap)
        if self.avoid is None:
            return reach
        return ir.And(reach, ir.Always(window, ir.Not(self.avoid)))

    @property
    def rho_bounds(self) -> tuple[float, float]:
        """Bounds of the robustness of ``asap`` over the state space (interval analysis)."""
        return formula_bounds(self.asap)

    @property
    def k_max(self) -> int:
        return self.episode[1]

    @property
    def rho_scale(self) -> float:
        """``1 / (rho_max - rho_min)``: the positive rescaling of ``r_sat auto`` (1 if unbounded)."""
        lo, hi = self.rho_bounds
        if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
            return 1.0
        return 1.0 / (hi - lo)

    @property
    def r_sat_bound(self) -> float:
        """The theorem's bound ``rho_max + (rho_max - rho_min) * k_max`` in raw units."""
        lo, hi = self.rho_bounds
        return hi + (hi - lo) * self.k_max

    @property
    def r_sat_value(self) -> float:
        """The reward once ``asap`` holds; for ``auto``, ``rho_max' + k_max + 1`` in scaled units."""
        if self.r_sat is not None:
            return self.r_sat
        lo, hi = self.rho_bounds
        if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
            return float(self.k_max + 1)
        return hi * self.rho_scale + self.k_max + 1


def formula_bounds(node: ir.Formula) -> tuple[float, float]:
    """Robustness bounds of a formula from its atoms' bounds over the state space.

    Temporal operators keep their argument's bounds: an empty window's ±inf (only at the first
    steps of a past window with a positive lower bound) is outside these bounds by design, and
    rewards clip into them.
    """
    if isinstance(node, ir.Atom):
        return node.bounds
    if isinstance(node, ir.Const):
        v = math.inf if node.value else -math.inf
        return (v, v)
    if isinstance(node, ir.Not):
        lo, hi = formula_bounds(node.arg)
        return (-hi, -lo)
    if isinstance(node, (ir.And, ir.Or, ir.Implies)):
        (a, b), (c, d) = formula_bounds(node.left), formula_bounds(node.right)
        if isinstance(node, ir.Implies):
            a, b = -b, -a
        if isinstance(node, ir.And):
            return (min(a, c), min(b, d))
        return (max(a, c), max(b, d))
    if isinstance(node, ir.UNARY_TEMPORAL):
        return formula_bounds(node.arg)
    (a, b), (c, d) = formula_bounds(node.left), formula_bounds(node.right)
    return (min(a, c), min(b, d))


@dataclass(frozen=True)
class ProgramModel:
    file: str
    source: str
    system: SystemModel
    regions: Mapping[str, RegionModel]
    formulas: Mapping[str, FormulaModel]
    tasks: Mapping[str, TaskModel]
    used: frozenset[str]
    declared: Mapping[str, tuple[str, Span]]  # name -> (kind, span)
