"""Failed starts: a curriculum on the initial states the learner has not yet solved.

A policy that reaches most of the init box soon stops seeing the states it fails on: they are a
few percent of the episodes, and their value estimates are starved. :class:`FailedStarts` keeps
the initial state of every training episode that ended without reaching ``asap`` (the env's
``t_reach``) and starts a share of the new episodes from them: each new episode, with probability
``share``, begins at one of those states drawn at random (and taken out of the pool), else at the
init box's draw. The pool holds the latest :data:`POOL_SIZE` failures. Every start is a state of
the init box, so the task is unchanged: only how often its hard states are practised.

Measured (docs/training.md, "Failed starts and long manoeuvres"): with half the new episodes from
failed starts and the oracle's longest sequences as demonstrations, the bicycle came 3 points and
attitude 3–5 points closer to their ceilings than the default without them.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from asap_dsl.env import core_of

__all__ = ["POOL_SIZE", "failed_starts_env"]

#: The failed starts remembered (the latest ones: an old failure may be solved by now).
POOL_SIZE = 2000


@functools.lru_cache(maxsize=1)
def _failed_starts_class():
    """Built on first use: stable-baselines3 loads only when a run trains."""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    class FailedStarts(VecEnvWrapper):
        """A raw vector env of the task (:class:`asap_dsl.env.AsapVecEnv`) whose new episodes start,
        with probability ``share``, at the initial state of an earlier episode that did not reach."""

        def __init__(self, venv, share: float, seed: int):
            super().__init__(venv)
            self.core = core_of(venv)
            self.share = float(share)
            self.rng = np.random.default_rng([int(seed), 77])
            self.pool: list[np.ndarray] = []
            self.starts = np.array(self.core.states, dtype=np.float64)
            self.replayed = 0

        def reset(self):
            obs = self.venv.reset()
            self.starts = np.array(self.core.states, dtype=np.float64)
            return obs

        def step_wait(self):
            obs, reward, done, infos = self.venv.step_wait()
            if not done.any():
                return obs, reward, done, infos
            ended = np.flatnonzero(done)
            self.pool.extend(self.starts[i].copy() for i in ended if infos[i].get("t_reach") is None)
            del self.pool[:-POOL_SIZE]
            take = np.zeros(len(done), dtype=bool)
            draws = self.rng.random(len(ended))
            for i, u in zip(ended, draws):
                take[i] = bool(self.pool) and u < self.share and take.sum() < len(self.pool)
            if take.any():
                cand = np.array(self.core.states, dtype=np.float64)
                for i in np.flatnonzero(take):
                    cand[i] = self.pool.pop(int(self.rng.integers(len(self.pool))))
                obs = np.array(obs)
                obs[take] = self.core.restart(take, cand)
                self.replayed += int(take.sum())
            self.starts[ended] = np.asarray(self.core.states)[ended]
            return obs, reward, done, infos

        def state(self) -> dict[str, Any]:
            """What a checkpoint keeps, so that a resumed run draws as the uninterrupted one."""
            return {"rng": self.rng.bit_generator.state, "pool": [p.tolist() for p in self.pool],
                    "starts": self.starts.tolist(), "replayed": self.replayed}

        def restore(self, state: dict[str, Any]) -> None:
            self.rng.bit_generator.state = state["rng"]
            self.pool = [np.asarray(p, dtype=np.float64) for p in state["pool"]]
            self.starts = np.asarray(state["starts"], dtype=np.float64)
            self.replayed = int(state["replayed"])

    return FailedStarts


def failed_starts_env(venv, share: float, seed: int):
    """``venv`` (a raw vector env of the task) with the failed-starts curriculum: each new episode
    starts, with probability ``share`` in [0, 1], at the initial state of an earlier episode that
    did not reach ``asap``. The rest of the learner's wrappers go around it."""
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"the share of failed starts must be in [0, 1]; got {share}")
    return _failed_starts_class()(venv, share, seed)
