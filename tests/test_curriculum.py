"""The default preset's two rules for the hard states: failed starts (a share of the new training
episodes start where an earlier one did not reach) and the oracle's longest manoeuvres as
demonstrations. Both cores restart an entry at a chosen state alike; the curriculum starts from
failures only, at the share asked for, and resumes as it was; the longest share is kept."""

from __future__ import annotations

import numpy as np
import pytest

import asap_dsl
from conftest import RAIL


@pytest.fixture(scope="module")
def rail():
    return asap_dsl.loads(RAIL, "rail.asap")


def _cores(prog, B: int):
    from asap_dsl.env import EnvCore
    from asap_dsl.native import with_engine

    plain = EnvCore(prog, None, B, None, autoreset=True)
    native = with_engine(EnvCore(prog, None, B, None, autoreset=True), "native")
    assert native.engine == "native"
    return plain, native


def test_both_cores_restart_chosen_entries_alike(rail):
    B = 6
    plain, native = _cores(rail, B)
    rng = np.random.default_rng(3)
    s0 = rng.uniform(-1.5, 1.5, size=(B, 1))
    for core in (plain, native):
        core.start(s0, 20)
    acts = rng.uniform(-1, 1, size=(5, B, 1))
    for a in acts[:3]:
        plain.step(a), native.step(a)
    mask = np.array([True, False, True, False, False, True])
    at = np.full((B, 1), 0.95)  # in the goal: t_reach is 0 at once
    at[0] = -1.0
    obs_p, obs_n = plain.restart(mask, at), native.restart(mask, at)
    assert obs_p.shape == (3, 1) and np.allclose(obs_p, obs_n)
    for core in (plain, native):
        assert np.allclose(np.asarray(core.states)[mask, 0], [-1.0, 0.95, 0.95])
        assert list(np.asarray(core.t)[mask]) == [0, 0, 0] and list(np.asarray(core.t)[~mask]) == [3, 3, 3]
        assert list(np.asarray(core.t_reach)[mask]) == [-1, 0, 0]
    for a in acts[3:]:
        out_p, out_n = plain.step(a), native.step(a)
        assert np.allclose(out_p[0], out_n[0]) and np.allclose(out_p[1], out_n[1])  # observations, rewards
    assert np.allclose(plain.states, native.states)


def _curriculum_env(prog, share: float, B: int = 4, seed: int = 0):
    from asap_dsl.backends.rl.curriculum import failed_starts_env
    from asap_dsl.env import make_vec_env

    return failed_starts_env(make_vec_env(prog, num_envs=B, seed=seed), share, seed)


def _run(env, steps: int, action: float) -> tuple[list, list]:
    """Step with a constant action; (initial states of the episodes begun, which began from the pool)."""
    env.reset()
    began, from_pool = [], []
    for _ in range(steps):
        before = env.replayed
        env.step_async(np.full((env.num_envs, 1), action))
        _, _, done, _ = env.step_wait()
        for i in np.flatnonzero(done):
            began.append(float(env.core.states[i, 0]))
        from_pool.append(env.replayed - before)
    return began, from_pool


def test_failed_episodes_start_again_at_the_share_asked_for(rail):
    env = _curriculum_env(rail, 1.0)
    env.reset()
    first = np.array(env.core.states[:, 0])
    for _ in range(40):  # standing still: no episode reaches, so every start is kept and replayed
        env.step_async(np.zeros((4, 1)))
        env.step_wait()
    assert env.replayed > 0
    starts = set(np.round(first, 9))
    assert set(np.round(np.asarray(env.core.states)[:, 0], 9)) <= starts  # only the failures' starts come back

    none = _curriculum_env(rail, 0.0)
    _, took = _run(none, 60, 0.0)
    assert sum(took) == 0 and none.pool  # failures remembered, never replayed

    half = _curriculum_env(rail, 0.5, B=16)
    _, took = _run(half, 200, 0.0)
    ended = 16 * 200 // 20  # episodes end at their length (at most the deadline, 20 steps)
    assert 0.3 * ended < sum(took) < 0.75 * ended


def test_reached_episodes_are_not_replayed(rail):
    env = _curriculum_env(rail, 1.0)
    env.reset()
    for _ in range(60):  # a controller that drives to x = 1: every episode reaches
        x = np.asarray(env.core.states)[:, 0]
        env.step_async(np.clip((1.0 - x) / 0.2, -1, 1)[:, None])
        env.step_wait()
    assert env.replayed == 0 and not env.pool


def test_the_curriculum_resumes_as_it_was(rail):
    a, b = _curriculum_env(rail, 0.5), _curriculum_env(rail, 0.5)
    for env in (a, b):
        _run(env, 50, 0.0)
    b.restore(a.state())
    draws_a = [a.rng.random() for _ in range(3)]
    draws_b = [b.rng.random() for _ in range(3)]
    assert draws_a == draws_b and len(a.pool) == len(b.pool) and np.allclose(a.pool, b.pool)
    with pytest.raises(ValueError, match="between|in \\[0, 1\\]"):
        _curriculum_env(rail, 1.5)


def test_the_longest_share_of_the_sequences_is_kept_repeated():
    from asap_dsl.backends.rl.demonstrations import Witnesses, longest

    seqs = [np.zeros((n, 1)) for n in (3, 9, 5, 9, 2, 7, 4, 6, 8, 1)]
    w = Witnesses(1, 12, np.arange(10.0)[:, None], seqs, np.full(10, 20))
    top = longest(w, 0.2, 3)
    assert [len(s) for s in top.sequences] == [9] * 6  # the two of 9 steps (the top fifth), three times each
    assert sorted(set(top.starts[:, 0])) == [1.0, 3.0] and top.solved == 10 and top.states == 12
    assert [len(s) for s in longest(w, 0.3, 1).sequences] == [9, 9, 8]
    assert longest(w) is w
    with pytest.raises(ValueError):
        longest(w, 0.0)


def test_the_default_preset_has_both_rules_sized_to_the_run(rail):
    from asap_dsl.backends.rl.config import ConfigError, resolve_config

    cfg = resolve_config(rail)
    assert cfg.failed_starts == 0.5 and cfg.stall_demonstrations == 300 and cfg.demonstration_share == 0.2
    assert cfg.demonstration_repeat == 4 and cfg.demonstration_seconds == 450.0  # the oracle's clock
    assert resolve_config(rail, steps=8000).stall_demonstrations == 10  # one state per 800 steps
    assert resolve_config(rail, time_limit=600).demonstration_seconds == 90.0  # 15% of a time limit
    assert resolve_config(rail, algo="ppo").stall_demonstrations == 0 and resolve_config(rail, algo="ppo").failed_starts == 0.5
    paper = resolve_config(rail, preset="paper")
    assert paper.failed_starts == 0.0 and paper.demonstrations == 0 == paper.stall_demonstrations
    assert resolve_config(rail, failed_starts=0).failed_starts == 0.0
    with pytest.raises(ConfigError, match="between 0 and 1"):
        resolve_config(rail, failed_starts=2)


def test_a_failure_earns_the_floor_for_ever_so_that_leaving_never_pays(rail):
    """Leaving the state space (or ``avoid``) ends the episode: with the floor earned once, a state
    the learner cannot solve is better left than struggled with (the bicycle's policy learnt that
    with failed starts). The default's learner earns it for every step after: floor / (1 - gamma)."""
    from asap_dsl.backends.rl.config import resolve_config
    from asap_dsl.env import make_vec_env

    cfg = resolve_config(rail)
    floor = make_vec_env(rail, num_envs=1).core.reward.floor
    assert floor < 0 and cfg.failure_reward == pytest.approx(floor / (1 - cfg.hyper["gamma"]))
    assert resolve_config(rail, preset="paper").failure_reward is None
    assert resolve_config(rail, reward="distance").failure_reward is None  # no floor to repeat
    env = make_vec_env(rail, num_envs=1, seed=0, failure_reward=cfg.failure_reward)
    env.reset()
    env.core.start(np.array([[-1.5]]), 20)
    rewards = []
    for _ in range(5):  # x' = 2u: two steps into the pit
        env.step_async(np.array([[-1.0]]))
        _, r, done, info = env.step_wait()
        rewards.append(float(r[0]))
        if done[0]:
            break
    assert info[0]["end_reason"] == "avoid" and rewards[-1] == pytest.approx(cfg.failure_reward, rel=1e-6)
    # no episode that goes on can earn less: every step earns at least the floor
    assert all(r >= floor - 1e-9 for r in rewards[:-1]) and sum(rewards[:-1]) > cfg.failure_reward


def test_when_the_discount_grows_mid_run_a_failure_still_earns_the_floor_for_ever(rail):
    """The late rule lengthens the discount's horizon (:mod:`.exploration`); the failure step's
    reward, floor / (1 - gamma), follows it in the learner's steps and in the stored ones."""
    from types import SimpleNamespace

    from asap_dsl.backends.rl.config import resolve_config
    from asap_dsl.backends.rl.session import LearnerEnv, Session
    from asap_dsl.env import make_vec_env

    cfg = resolve_config(rail)
    floor = make_vec_env(rail, num_envs=1).core.reward.floor
    learner = LearnerEnv(make_vec_env(rail, num_envs=1, seed=0, failure_reward=cfg.failure_reward), False)
    stored = np.array([[cfg.failure_reward], [0.5]], dtype=np.float32)
    model = SimpleNamespace(gamma=cfg.hyper["gamma"], replay_buffer=SimpleNamespace(rewards=stored))
    session = SimpleNamespace(cfg=cfg, failure_reward=cfg.failure_reward, env=SimpleNamespace(venv=learner))
    Session.set_discount(session, model, 0.99)
    assert model.gamma == 0.99 and session.failure_reward == pytest.approx(floor / (1 - 0.99))
    assert stored[0, 0] == pytest.approx(floor / (1 - 0.99), rel=1e-6) and stored[1, 0] == 0.5

    def episode(start: float, action: float) -> tuple[list[float], dict]:
        learner.reset()
        learner.venv.core.start(np.array([[start]]), 20)
        rewards = []
        while True:
            learner.step_async(np.array([[action]]))
            _, r, done, info = learner.step_wait()
            rewards.append(float(r[0]))
            if done[0]:
                return rewards, info[0]

    rewards, info = episode(-1.5, -1.0)  # into the pit: a failure
    assert info["end_reason"] == "avoid" and rewards[-1] == pytest.approx(floor / (1 - 0.99), rel=1e-6)
    rewards, info = episode(1.0, 0.0)  # staying put until the deadline: no failure, rewards as they were
    assert info["TimeLimit.truncated"] and min(rewards) > floor / (1 - 0.99) / 2
