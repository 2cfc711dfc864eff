"""The checker: AST to :class:`~asap_dsl.model.ProgramModel`, reporting every problem at once.

It resolves names (suggesting the closest declared one), tells conditions from numbers, folds
constants, converts times to steps, checks causality and builds the formula IR. It never stops at
the first problem: each part is checked on its own and a broken part is left out of the model,
so that the rest still gets checked. Model-level rules (overlaps, bounds, unused names, ...) are
lint rules in :mod:`asap_dsl.lint`.

The parts share one explicit :class:`~asap_dsl.checker_common.CheckState` and take what they
need: names, numbers and times (:class:`~asap_dsl.checker_exprs.Numbers`), conditions and formula
declarations (:class:`~asap_dsl.checker_exprs.Conditions`), the system and its regions
(:mod:`asap_dsl.checker_system`), tasks (:mod:`asap_dsl.checker_tasks`). :class:`Checker` puts
them together.
"""

from __future__ import annotations

from typing import Optional

from . import ast
from .checker_common import CONST, CheckState, _Unresolved
from .checker_exprs import Conditions, Numbers
from .checker_system import SystemChecks
from .checker_tasks import TaskChecks, reward_model
from .diagnostics import Collector, Diagnostic, Span
from .model import ProgramModel, RewardModel, TaskModel


class Checker:
    """One module's check: the shared state and the parts over it (see the module docstring)."""

    def __init__(self, module: ast.Module, source: str, diag: Collector):
        self.state = CheckState(module, source, diag)
        self.numbers = Numbers(self.state)
        self.conditions = Conditions(self.state, self.numbers)
        self.system = SystemChecks(self.state, self.numbers)
        self.tasks = TaskChecks(self.state, self.numbers, self.conditions)

    def run(self) -> Optional[ProgramModel]:
        s = self.state
        system = self.system.check_system()
        self.system.check_regions()
        self.conditions.check_formulas()
        tasks: dict[str, TaskModel] = {}
        for t in s.module.tasks:
            if not s.declared_here(t.name, t.name_span):
                continue
            model = self.tasks.check_task(t)
            if model is not None:
                tasks[t.name] = model
        if system is None:
            return None
        # With errors elsewhere the model is partial (broken parts left out); lint rules still run
        # on it so that a file's problems are all reported at once, and the caller discards it.
        return ProgramModel(s.module.file, s.source, system, dict(s.regions), dict(s.formulas), tasks,
                            frozenset(s.used), dict(s.kinds))


def check(module: ast.Module, source: str, diag: Collector) -> Optional[ProgramModel]:
    """Check a parsed module; diagnostics go to ``diag``.

    The model is None when there is no usable system; it is partial when ``diag`` has errors.
    """
    return Checker(module, source, diag).run()


def check_reward(syn: ast.RewardSyntax, source: str, file: str, dt: Optional[float] = None
                 ) -> tuple[Optional[RewardModel], list[Diagnostic]]:
    """A reward written on its own (``asapc train --reward``), checked as a task's ``reward``
    clause is, where the only names are the built-in constants and ``dt`` (seconds per step, if
    given: ``rho(window = 1s)`` needs it). The model (None on errors) and the diagnostics."""
    diag = Collector(file)
    state = CheckState(ast.Module(file, (), (), (), ()), source, diag)
    if dt is not None:
        state.dt, state.consts["dt"], state.kinds["dt"] = dt, dt, (CONST, Span())
    try:
        return reward_model(syn, Numbers(state)), diag.items
    except _Unresolved:
        return None, diag.items
