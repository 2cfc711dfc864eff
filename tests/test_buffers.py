"""The flat-gather replay buffer draws exactly what stable-baselines3's draws (the same rows, the
same values, time-outs not counted as ends), and off-policy models are built with it."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces

import asap_dsl
from conftest import RAIL


def _filled(cls, n_envs: int = 3, size: int = 60):
    buf = cls(size, spaces.Box(-1, 1, (2,), np.float32), spaces.Box(-1, 1, (1,), np.float32), n_envs=n_envs)
    rng = np.random.default_rng(1)
    for _ in range(size // n_envs + 4):  # wraps around: the buffer is full
        done = rng.random(n_envs) < 0.3
        infos = [{"TimeLimit.truncated": bool(d and rng.random() < 0.5)} for d in done]
        buf.add(rng.normal(size=(n_envs, 2)), rng.normal(size=(n_envs, 2)), rng.uniform(-1, 1, (n_envs, 1)),
                rng.normal(size=n_envs), done, infos)
    return buf


@pytest.mark.parametrize("n_envs", [1, 3])
def test_the_flat_buffer_draws_what_stable_baselines3_draws(n_envs):
    from stable_baselines3.common.buffers import ReplayBuffer

    from asap_dsl.backends.rl.buffers import FlatReplayBuffer

    ref, flat = _filled(ReplayBuffer, n_envs), _filled(FlatReplayBuffer, n_envs)
    assert ref.full and flat.full and flat.timeouts.any() and (flat.dones * (1 - flat.timeouts)).any()
    for seed in range(5):
        np.random.seed(seed)
        a = ref.sample(256)
        np.random.seed(seed)
        b = flat.sample(256)
        for x, y in zip(a, b):
            if x is None:  # n-step discounts: neither has them
                assert y is None
                continue
            assert x.dtype == y.dtype and x.shape == y.shape
            assert np.array_equal(x.numpy(), y.numpy())


@pytest.mark.parametrize("engine", ["sb3", "sbx"])
def test_off_policy_models_are_built_with_it_unless_the_settings_choose(engine, tmp_path):
    from asap_dsl.backends.rl.buffers import FlatReplayBuffer

    prog = asap_dsl.loads(RAIL, "rail.asap")
    res = asap_dsl.train(prog, steps=300, n_envs=2, engine=engine, out=tmp_path / "r", evaluate=False,
                         demonstrations=0, settings={"net_arch": [8, 8], "learning_starts": 100, "batch_size": 16})
    from asap_dsl.backends.rl.engines import get_engine

    model = get_engine(engine).load("sac", res.run_dir / "checkpoint" / "model.zip")
    assert model.replay_buffer_class is FlatReplayBuffer
    from asap_dsl.backends.rl.sb3 import model_kwargs

    assert "replay_buffer_class" not in model_kwargs("ppo", spaces.Box(-1, 1, (1,)), {}, engine)


def test_a_buffer_chosen_by_the_settings_or_n_step_returns_is_left_alone():
    from stable_baselines3.common.buffers import ReplayBuffer

    from asap_dsl.backends.rl.buffers import FlatReplayBuffer, default_buffer

    assert default_buffer({}) is FlatReplayBuffer and default_buffer({"n_steps": 1}) is FlatReplayBuffer
    assert default_buffer({"replay_buffer_class": ReplayBuffer}) is None
    assert default_buffer({"n_steps": 3}) is None  # sbx's n-step buffer
