"""Initial states: uniform in the ``init`` box, the same for every method given the same seed.

Training (Algorithm 1: ``s0 ~ U(init box)``), evaluation and the oracle all draw from here, so
that a paired comparison really compares methods on the same states. A state where ``avoid``
already holds at step 0 is redrawn: an episode cannot be judged on a start it cannot change.
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from .model import SystemModel
from .stl import ir

EVAL_SEED = 2024  # the default seed of `asapc eval` and `asapc oracle`
#: The error when 100 rounds of redraws found no initial state outside ``avoid``.
INIT_BOX_IN_AVOID = "the init box lies (almost) entirely inside `avoid`: no initial state could be drawn outside it"


Box = tuple  # (low, high): a task's own initial box, or None for the system's


def init_box(system: SystemModel, box: Optional[Box] = None) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) of the initial states: ``box`` (a task's ``init box(...)``) or the system's."""
    if box is None:
        return system.init_low, system.init_high
    return np.asarray(box[0], dtype=float), np.asarray(box[1], dtype=float)


def initial_states(system: SystemModel, n: int, rng: np.random.Generator,
                   avoid: Optional[ir.Formula] = None, max_rounds: int = 100, box: Optional[Box] = None,
                   holds: Optional[Callable[[np.ndarray], np.ndarray]] = None) -> np.ndarray:
    """``n`` states drawn uniformly from the init box (a task's own, or the system's), none of
    them in ``avoid`` at step 0. ``holds(states [m, n]) -> bool [m]`` says where ``avoid`` holds
    at step 0 (default: the offline evaluator; the compiled step passes its own, same values)."""
    low, high = init_box(system, box)
    out = rng.uniform(low, high, size=(n, system.n_state))
    if avoid is None:
        return out
    if holds is None:
        from .stl import offline

        def holds(states: np.ndarray) -> np.ndarray:
            return offline.satisfied(avoid, states[:, None, :])[:, 0]

    for _ in range(max_rounds):
        bad = holds(out)
        if not bad.any():
            return out
        out[bad] = rng.uniform(low, high, size=(int(bad.sum()), system.n_state))
    raise ValueError(INIT_BOX_IN_AVOID)


def evaluation_states(system: SystemModel, n: int, seed: int = EVAL_SEED, avoid: Optional[ir.Formula] = None,
                      box: Optional[Box] = None) -> np.ndarray:
    """The seeded initial states of ``asapc eval`` and ``asapc oracle`` (paired across methods)."""
    return initial_states(system, n, np.random.default_rng(seed), avoid, box=box)


def task_states(system: SystemModel, task, n: int, seed: int = EVAL_SEED) -> np.ndarray:
    """The seeded initial states of a task (its ``avoid``, its initial box)."""
    return evaluation_states(system, n, seed, task.avoid, task.init_box)
