"""The abstract syntax tree: frozen dataclasses, every node with its source span.

The parser builds these straight from Lark's tree; nothing here resolves names or checks
meaning (that is :mod:`asap_dsl.checker`). Arithmetic and conditions share one expression type,
as they share one precedence ladder in the grammar; the checker tells them apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Union

from .diagnostics import Span

# ------------------------------------------------------------------ expressions and formulas


@dataclass(frozen=True)
class Number:
    value: float
    span: Span


@dataclass(frozen=True)
class Infinity:
    span: Span


@dataclass(frozen=True)
class Name:
    id: str
    span: Span


@dataclass(frozen=True)
class Call:
    func: str
    args: tuple["Expr", ...]
    span: Span
    func_span: Span


@dataclass(frozen=True)
class Unary:
    """Arithmetic negation (``op == "-"``)."""

    op: str
    arg: "Expr"
    span: Span


@dataclass(frozen=True)
class Binary:
    """Arithmetic: ``+ - * / ^``."""

    op: str
    left: "Expr"
    right: "Expr"
    span: Span


@dataclass(frozen=True)
class Compare:
    """``left op right`` with op in ``< <= > >= == !=``."""

    op: str
    left: "Expr"
    right: "Expr"
    span: Span
    op_span: Span


@dataclass(frozen=True)
class BoolLiteral:
    value: bool
    span: Span


@dataclass(frozen=True)
class InRegion:
    region: str
    span: Span
    name_span: Span


@dataclass(frozen=True)
class Not:
    arg: "Expr"
    span: Span


@dataclass(frozen=True)
class Logic:
    """``and``, ``or`` or ``implies`` (canonical spellings, whatever alias was written)."""

    op: str
    left: "Expr"
    right: "Expr"
    span: Span


@dataclass(frozen=True)
class Conditional:
    """``if test then then_ else else_``: a number chosen by a test on numbers at this step
    (comparisons, joined by ``and``/``or``/``not``)."""

    test: "Expr"
    then_: "Expr"
    else_: "Expr"
    span: Span


@dataclass(frozen=True)
class Duration:
    """A time as written: ``value`` with ``unit`` in ``steps``, ``s``, ``ms``; ``inf`` allowed."""

    value: float
    unit: str
    span: Span

    @property
    def is_inf(self) -> bool:
        return self.value == float("inf")


@dataclass(frozen=True)
class IntervalSyntax:
    lo: Duration
    hi: Duration
    span: Span


@dataclass(frozen=True)
class Temporal:
    """A unary temporal operator, canonical name (``always`` ...), interval or None (= [0, inf])."""

    op: str
    interval: Optional[IntervalSyntax]
    arg: "Expr"
    span: Span
    op_span: Span


@dataclass(frozen=True)
class Temporal2:
    """``until`` or ``since``."""

    op: str
    interval: Optional[IntervalSyntax]
    left: "Expr"
    right: "Expr"
    span: Span
    op_span: Span


Expr = Union[Number, Infinity, Name, Call, Unary, Binary, Compare, BoolLiteral, InRegion, Not, Logic, Temporal, Temporal2,
             Conditional]

# ------------------------------------------------------------------ the system


@dataclass(frozen=True)
class Range:
    lo: Expr
    hi: Expr
    span: Span


@dataclass(frozen=True)
class ConstDecl:
    name: str
    value: Expr
    span: Span
    name_span: Span


@dataclass(frozen=True)
class StateDecl:
    name: str
    space: Range
    init: Optional[Range]
    span: Span
    name_span: Span


@dataclass(frozen=True)
class ActionDecl:
    name: str
    bounds: Range
    span: Span
    name_span: Span


@dataclass(frozen=True)
class LetDecl:
    name: str
    value: Expr
    span: Span
    name_span: Span


@dataclass(frozen=True)
class Equation:
    target: str
    value: Expr
    span: Span
    target_span: Span


@dataclass(frozen=True)
class Dynamics:
    """``kind`` is ``ode`` or ``map``."""

    kind: str
    equations: tuple[Equation, ...]
    span: Span


@dataclass(frozen=True)
class SimulatorDecl:
    target: str
    span: Span


@dataclass(frozen=True)
class Setting:
    name: str
    value: Union[Expr, str]
    span: Span
    name_span: Span


@dataclass(frozen=True)
class ListValue:
    """``[64, 64]``: a list, as a training setting's value (``net_arch = [64, 64]``)."""

    items: tuple[object, ...]
    span: Span


@dataclass(frozen=True)
class ObjectValue:
    """``{pi: [64], qf: [400, 300]}``: named values, as a training setting's value; each entry is
    ``(name, value, name_span)``."""

    entries: tuple[tuple[str, object, Span], ...]
    span: Span


@dataclass(frozen=True)
class IntegratorDecl:
    method: str
    settings: tuple[Setting, ...]
    span: Span
    method_span: Span


@dataclass(frozen=True)
class System:
    name: str
    consts: tuple[ConstDecl, ...]
    states: tuple[StateDecl, ...]
    actions: tuple[ActionDecl, ...]
    lets: tuple[LetDecl, ...]
    dt: tuple[Expr, ...]  # all `dt =` lines (the checker wants exactly one)
    dynamics: tuple[Union[Dynamics, SimulatorDecl], ...]
    integrators: tuple[IntegratorDecl, ...]
    span: Span
    name_span: Span


# ------------------------------------------------------------------ regions, formulas, tasks


@dataclass(frozen=True)
class Coord:
    name: str
    value: Expr
    span: Span


@dataclass(frozen=True)
class Ball:
    centre: Union[tuple[Expr, ...], tuple[Coord, ...]]
    named: bool  # {x: 1, y: 2} rather than [1, 2, ...]
    radius: Expr
    span: Span
    centre_span: Span


@dataclass(frozen=True)
class BoxSide:
    var: str
    bounds: Range
    span: Span


@dataclass(frozen=True)
class Box:
    sides: tuple[BoxSide, ...]
    span: Span


@dataclass(frozen=True)
class RegionDecl:
    name: str
    shape: Union[Ball, Box]
    span: Span
    name_span: Span


@dataclass(frozen=True)
class FormulaDecl:
    name: str
    body: Expr
    span: Span
    name_span: Span


@dataclass(frozen=True)
class Clause:
    """One task clause: ``keyword`` and its payload (type depends on the keyword)."""

    keyword: str
    value: object
    span: Span


@dataclass(frozen=True)
class RewardSyntax:
    kind: str
    settings: tuple[Setting, ...]
    span: Span


@dataclass(frozen=True)
class TaskDecl:
    name: str
    clauses: tuple[Clause, ...]
    span: Span
    name_span: Span


@dataclass(frozen=True)
class Module:
    """A whole file."""

    file: str
    systems: tuple[System, ...]
    regions: tuple[RegionDecl, ...]
    formulas: tuple[FormulaDecl, ...]
    tasks: tuple[TaskDecl, ...]
