"""The oracle's simulated clock: its time limits read as work done, not as seconds on the wall.

A training run's demonstrations must be the same on every machine: on the wall clock a slower
machine solves fewer states within a state's limit and a search's budget, and the run then learns
from less (the planner's demonstrations showed it: docs/training.md, "The planner's clock is
simulated"). Under a :class:`WorkClock` the oracle counts what its NLP solves compute, which does
not depend on the machine, and charges each unit the CPU seconds it took on a 2-core machine like
that of docs/results; a slower machine then takes longer and finds the same.

Measured (process time of the search of 8 states per task of 15 tasks: the four benchmarks' and
the examples'; a training sweep held the cores meanwhile), the three terms priced below came within 0.56-1.24 of the time taken per task
(the median 0.95): the callbacks (``n_call`` of IPOPT's functions times their CasADi instructions),
the linear algebra (iterations times the NLP's variables) and the work around each solve (its
initial guess, the rollout of its solution, the checks). The bicycle's searches cost about 1.6x
what they are charged, DC motor's 0.8x.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["WorkClock", "Work"]


@dataclass
class Work:
    """What the NLP solves computed so far (:class:`~asap_dsl.backends.oracle.nlp.ShootingProblems`
    counts it): CasADi instructions evaluated in IPOPT's callbacks, IPOPT iterations times the
    NLP's variables, and solves."""

    instructions: int = 0
    variable_iterations: int = 0
    solves: int = 0

    def since(self, earlier: "Work") -> "Work":
        return Work(self.instructions - earlier.instructions, self.variable_iterations - earlier.variable_iterations,
                    self.solves - earlier.solves)

    def copy(self) -> "Work":
        return Work(self.instructions, self.variable_iterations, self.solves)


@dataclass(frozen=True)
class WorkClock:
    """CPU seconds charged per unit of :class:`Work` (fitted as the module says)."""

    per_instruction: float = 1.2e-8
    per_variable_iteration: float = 6.4e-6
    per_solve: float = 0.011

    def seconds(self, work: Work) -> float:
        """The simulated seconds of ``work``."""
        return (work.instructions * self.per_instruction + work.variable_iterations * self.per_variable_iteration
                + work.solves * self.per_solve)

    def tag(self) -> str:
        """A short name of the rates (a cache key's part: another clock finds other states)."""
        return f"{self.per_instruction:g}-{self.per_variable_iteration:g}-{self.per_solve:g}"
