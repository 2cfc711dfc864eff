"""A smaller learning rate once validation has stopped improving (a refinement for precision).

The success rate at the tightest tolerance is a matter of a step or two on most states: the
policy's switching times. Once the validation score has not improved for ``patience``
validations in a row, :class:`PlateauDrop` multiplies the learning rate by ``factor``, once per
run; the model's own ``learning_rate`` is changed (and its schedule rebuilt), so a checkpoint
and a resumed run keep it. Both engines read the schedule before each update.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Optional

__all__ = ["PlateauDrop", "set_learning_rate"]


@dataclass
class PlateauDrop:
    """The rule's state: the best score so far, the validations since, and whether it has fired
    (``at_step``: where)."""

    factor: float
    patience: int
    best: float = float("-inf")
    since: int = 0
    at_step: Optional[int] = None

    def seen(self, score: float, steps: int) -> bool:
        """Record a validation's score; True when the learning rate is to be dropped now."""
        if score > self.best + 1e-9:
            self.best, self.since = float(score), 0
            return False
        self.since += 1
        if self.at_step is None and self.since >= self.patience:
            self.at_step = int(steps)
            return True
        return False

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "PlateauDrop":
        return cls(**data)


def set_learning_rate(model, learning_rate: float) -> None:
    """A constant learning rate for the rest of ``model``'s training (stable-baselines3 and sbx
    alike: both rebuild ``lr_schedule`` from ``learning_rate``, on load too)."""
    model.learning_rate = float(learning_rate)
    model._setup_lr_schedule()
