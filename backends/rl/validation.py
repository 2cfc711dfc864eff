"""Validation during training: how many initial states, when, and what is written of it.

The rule (stated in the run's progress): a run validates on ``min(preset's states, max(100,
steps / 50))`` states of its own seed, so a short run does not spend its time judging; at most the
preset's number of times, evenly spaced in steps (or on the clock for a time-limited run); and a
due validation waits while the validations so far plus one more would step their states for more
environment steps than training has taken (a validation steps each state for the task's longest
episode at most). The first due one always runs, and so does one at the end, on the final policy.
The budget is counted in steps, not seconds: validation steps its states in one batch while a
training step carries its gradient updates, so this is a few per cent of the time, and unlike the
clock it is the same on every machine. Measured on the clock, a run retried on a slower node (its
first steps compiling) validated every period where the first try had waited, ended on its plateau
at another step, and the sweep's report changed with the load. A tie keeps the later model (trained
longer: a run whose validations all score 0 ends with its latest policy, not its first).

Each validation is a row of ``curves.csv`` and, at the same step, TensorBoard's
``validation/*`` scalars beside stable-baselines3's own ``rollout/ep_rew_mean`` and
``rollout/ep_len_mean`` (episodes finished since the last dump).
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from typing import Mapping, Optional

import numpy as np

__all__ = ["BUDGET", "PLATEAU_GAIN", "Schedule", "plateau_reached", "validation_score", "validation_states",
           "write_curves"]

#: Validation's environment steps (its states times the longest episode) at most this many times
#: the training's.
BUDGET = 1.0
MIN_STATES = 100
STEPS_PER_STATE = 50


#: What counts as progress of the validation score (the mean rate over the tolerances): within
#: this of the best so far. The noise of 500 validation states is about 2 points at a 60% rate.
PLATEAU_GAIN = 0.01
#: Validations before a run may end on a plateau.
PLATEAU_VALIDATIONS = 3


def plateau_reached(curves: list[dict], steps: int, share: float) -> bool:
    """Whether validation has stopped improving: the latest ``share`` of the ``steps`` done has
    brought the score nothing within :data:`PLATEAU_GAIN` of its best that it had not reached
    before (its first validation that close to the best came at ``steps * (1 - share)`` or
    earlier), after :data:`PLATEAU_VALIDATIONS` validations at least. With ``share`` one half, a
    run ends once it has trained as long again as its progress took."""
    if len(curves) < PLATEAU_VALIDATIONS:
        return False
    best = max(r["score"] for r in curves)
    reached = min(r["steps"] for r in curves if r["score"] >= best - PLATEAU_GAIN)
    return reached <= steps * (1.0 - share)


def validation_score(rates: Mapping[int, float]) -> float:
    """How validations rank models: the mean success rate over the task's tolerances."""
    return float(np.mean(list(rates.values()))) if rates else 0.0


def validation_states(steps: int, preset_states: int) -> int:
    """The validation states of a run of ``steps`` environment steps (the module's rule)."""
    return int(min(preset_states, max(MIN_STATES, steps // STEPS_PER_STATE)))


def rule_text(states: int, validations: int) -> str:
    """The rule as the progress states it."""
    return (f"validation: {states:,} states, up to {validations} times, each only while validation's steps stay "
            f"within {BUDGET:g}x training's")


@dataclass
class Schedule:
    """When a run validates: every ``every`` steps (and every ``every_seconds`` on the clock for a
    time-limited run), within the budget: a validation costs ``cost`` environment steps (its
    states times the task's longest episode). ``count``: validations so far; ``spent``: their
    seconds (said at the end of a run), ``last``: the latest one's seconds (all kept in the checkpoint)."""

    every: int
    every_seconds: Optional[float] = None
    cost: int = 0
    next_step: int = 0
    next_time: float = float("inf")
    count: int = 0
    spent: float = 0.0
    last: float = 0.0

    def __post_init__(self) -> None:
        if not self.next_step:
            self.next_step = self.every
        if self.every_seconds is not None and self.next_time == float("inf"):
            self.next_time = self.every_seconds

    def due(self, steps: int, seconds: float) -> bool:
        """A validation is due at ``steps`` after ``seconds`` of the run, and fits the budget."""
        if steps < self.next_step and seconds < self.next_time:
            return False
        if self.count > 0 and (self.count + 1) * self.cost > BUDGET * steps:
            return False  # waits: it is retried at the next step
        return True

    def done(self, steps: int, seconds: float, cost: float) -> None:
        """A validation at ``steps`` took ``cost`` seconds; the next is a period later."""
        self.count += 1
        self.spent += cost
        self.last = cost
        while self.next_step <= steps:
            self.next_step += self.every
        if self.every_seconds is not None:
            self.next_time = seconds + self.every_seconds

    def restart_clock(self, seconds: float, left: float, count: int) -> None:
        """Validations on the clock spread over the ``left`` seconds from ``seconds`` (after the
        demonstrations took their share)."""
        if self.every_seconds is not None:
            self.every_seconds = left / max(1, count)
            self.next_time = seconds + self.every_seconds

    def to_dict(self) -> dict:
        return {"next_validation": self.next_step, "validations": self.count, "validation_seconds": self.spent,
                "last_validation_seconds": self.last}

    def restore(self, state: Mapping, validations: int) -> None:
        """From a checkpoint's state; ``validations``: the run's curves' rows (a checkpoint from
        before the count was kept)."""
        self.next_step = int(state["next_validation"])
        self.count = int(state.get("validations", validations))
        self.spent = float(state.get("validation_seconds", 0.0))  # checkpoints from before the budget
        self.last = float(state.get("last_validation_seconds", 0.0))


def write_curves(run, rows: list[dict], tolerances) -> None:
    """``curves.csv``: one row per validation (``return``: the validation episodes' mean return,
    empty in rows from runs recorded before it was kept)."""
    buf = io.StringIO()
    cols = ["steps", "seconds", "score", "best"] + [f"success_{T}" for T in tolerances] + ["return"]
    w = csv.DictWriter(buf, fieldnames=cols, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({**r, **{f"success_{T}": f"{v:.6f}" for T, v in r["rates"].items()}})
    run.write_curves(buf.getvalue())


def log_validation(model, logger, steps: int, rates: Mapping[int, float], score: float) -> None:
    """The validation's rates and SB3's rollout means into TensorBoard at ``steps`` (the step of
    its ``curves.csv`` row), written now."""
    from stable_baselines3.common.utils import safe_mean

    for T, v in rates.items():
        logger.record(f"validation/success_{T}", v)
    logger.record("validation/score", score)
    episodes = getattr(model, "ep_info_buffer", None)
    if episodes:
        logger.record("rollout/ep_rew_mean", safe_mean([e["r"] for e in episodes]))
        logger.record("rollout/ep_len_mean", safe_mean([e["l"] for e in episodes]))
    logger.dump(step=steps)
