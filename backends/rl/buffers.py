"""The replay buffer off-policy runs train with: stable-baselines3's ``ReplayBuffer``, drawing a
batch with one flat gather per array.

stable-baselines3 indexes each of its arrays (steps x environments x values) with two index
arrays and copies the batch into torch tensors; sbx turns them back into numpy. On a buffer of a
million transitions every row is a cache miss, and that indexing cost 290 us for a batch of 1024
against 78 us for ``np.take`` on the same rows (``benchmarks/engines.py`` measures the whole
training). The rows drawn are the same: the environment indices come from the same generator call
as stable-baselines3's, so a run samples exactly what it sampled before. Everything else (adding
transitions, the demonstrations written into the arrays, pickling in a checkpoint) is the parent's.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples

__all__ = ["FlatReplayBuffer"]


class FlatReplayBuffer(ReplayBuffer):
    """stable-baselines3's replay buffer whose batches are gathered with flat row indices."""

    def _get_samples(self, batch_inds: np.ndarray, env=None) -> ReplayBufferSamples:
        if self.optimize_memory_usage:  # next observations live in the next row: the parent's way
            return super()._get_samples(batch_inds, env=env)
        env_indices = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))  # as the parent draws them
        rows = batch_inds * self.n_envs + env_indices
        size = self.buffer_size * self.n_envs

        def take(a: np.ndarray) -> np.ndarray:
            return np.take(a.reshape(size, *a.shape[2:]), rows, axis=0)

        data = (
            self._normalize_obs(take(self.observations), env),
            take(self.actions),
            self._normalize_obs(take(self.next_observations), env),
            (take(self.dones) * (1 - take(self.timeouts))).reshape(-1, 1),  # a time-out is not an end
            self._normalize_reward(take(self.rewards).reshape(-1, 1), env),
        )
        return ReplayBufferSamples(*(th.as_tensor(x, device=self.device) for x in data))


def default_buffer(kwargs: dict) -> Optional[type]:
    """The buffer class for an off-policy model built with ``kwargs``: this module's, unless the
    settings chose one or ask for n-step returns (sbx's own buffer for them)."""
    if kwargs.get("replay_buffer_class") is not None or int(kwargs.get("n_steps", 1) or 1) != 1:
        return None
    return FlatReplayBuffer
