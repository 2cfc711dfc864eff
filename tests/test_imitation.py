"""The actor's imitation of the oracle's paths (backends/rl/imitation.py) and the default preset's
rule that turns it on (SAC on the sbx engine, known dynamics)."""

from __future__ import annotations

import numpy as np
import pytest

import asap_dsl
from asap_dsl.backends.rl.config import resolve_config
from asap_dsl.backends.rl.presets import DEFAULT

from conftest import RAIL

pytest.importorskip("sbx")


def _model(seed: int = 0):
    import gymnasium as gym

    from asap_dsl.backends.rl.engines import get_engine

    env = gym.make("Pendulum-v1")
    model = get_engine("sbx")._model_class("sac")("MlpPolicy", env, seed=seed, learning_starts=0, batch_size=64,
                                                 policy_kwargs={"net_arch": [32, 32]})
    rng = np.random.default_rng(0)
    buf = model.replay_buffer
    for _ in range(256):  # "demonstrations": the action +0.6 (in the policy's [-1, 1]) everywhere
        obs = rng.uniform(-1, 1, size=(1, 3)).astype(np.float32)
        buf.add(obs, obs, np.array([[0.6]], np.float32), np.array([-1.0]), np.array([False]), [{}])
    model._setup_learn(total_timesteps=1)
    return model, buf.observations[:256, 0]


def _actions(model, obs) -> np.ndarray:
    return model.predict(obs, deterministic=True)[0][:, 0] / 2.0  # Pendulum's torque bound is 2


def test_the_actor_is_pulled_towards_the_demonstrated_actions():
    from asap_dsl.backends.rl.imitation import set_imitation

    off, obs = _model()
    on, _ = _model()
    set_imitation(on, 5.0, 256)
    for m in (off, on):
        m.train(gradient_steps=500, batch_size=64)
    gap_on = np.abs(_actions(on, obs) - 0.6).mean()
    gap_off = np.abs(_actions(off, obs) - 0.6).mean()
    assert gap_on < 0.1 and gap_off > 0.4, (gap_on, gap_off)


def test_without_weight_or_rows_it_trains_exactly_as_sbx_sac():
    import jax
    import sbx

    from asap_dsl.backends.rl.imitation import set_imitation

    ours, obs = _model(seed=3)
    set_imitation(ours, 5.0, 0)  # a weight but no demonstration rows: off
    ours.train(gradient_steps=20, batch_size=64)
    theirs, _ = _model(seed=3)
    sbx.SAC.train(theirs, gradient_steps=20, batch_size=64)
    same = jax.tree_util.tree_map(lambda a, b: bool(np.array_equal(a, b)), ours.policy.actor_state.params,
                                  theirs.policy.actor_state.params)
    assert all(jax.tree_util.tree_leaves(same))


def test_imitation_is_asked_for_and_then_on_known_dynamics_with_sac_on_sbx_only():
    from asap_dsl.backends.rl.config import ConfigError

    prog = asap_dsl.loads(RAIL, "rail.asap")
    default = resolve_config(prog, steps=2_000_000)
    assert default.imitation == DEFAULT.imitation == 0.1 and default.key["imitation"] == 0.1  # the default does
    assert resolve_config(prog, steps=2_000_000, algo="td3").imitation == 0.0  # ... where it can, silently
    cfg = resolve_config(prog, steps=2_000_000, imitation=1.0)
    assert cfg.imitation == 1.0 and cfg.key["imitation"] == 1.0
    assert cfg.demonstrations == DEFAULT.imitation_states and cfg.stall_demonstrations == DEFAULT.demonstrations
    assert cfg.imitation_seconds == DEFAULT.imitation_seconds
    assert resolve_config(prog, steps=2_000_000, time_limit=600, imitation=1.0).imitation_seconds == pytest.approx(
        min(DEFAULT.imitation_seconds, DEFAULT.imitation_time_share * 600))
    short = resolve_config(prog, steps=8_000, imitation=1.0)
    assert short.demonstrations == 8_000 // DEFAULT.demonstration_steps  # a short run, a short search
    assert resolve_config(prog, steps=8_000, imitation=1.0, demonstrations=40).demonstrations == 40  # the run's own
    assert resolve_config(prog, steps=8_000, imitation=1.0, demonstrations=0).imitation == 0.0  # none to imitate
    for other, words in ((dict(algo="td3"), "only SAC on the sbx engine imitates; this run trains TD3 on sbx"),
                         (dict(engine="sb3"), "only SAC on the sbx engine imitates; this run trains SAC on sb3")):
        with pytest.raises(ConfigError, match=words):
            resolve_config(prog, steps=2_000_000, imitation=1.0, **other)
    with pytest.raises(ConfigError, match="must be a number of 0 or more"):
        resolve_config(prog, imitation=-1.0)
    assert "imitation" not in resolve_config(prog, steps=2_000_000, imitation=0).key  # runs without it keep their key


def test_the_late_rule_imitates_where_a_run_could_and_leaves_the_key_alone():
    prog = asap_dsl.loads(RAIL, "rail.asap")
    cfg = resolve_config(prog, steps=2_000_000, imitation=0)  # not imitating from the start
    assert cfg.sparse_imitation == DEFAULT.sparse_imitation > 0 and cfg.imitation_states == DEFAULT.imitation_states
    assert cfg.imitation_seconds == DEFAULT.imitation_seconds
    assert "sparse_imitation" not in cfg.key and "imitation_states" not in cfg.key  # acts only once it fired
    assert cfg.sparse_gamma is None  # imitating the paths, the run keeps its discount
    for other in (dict(algo="td3"), dict(engine="sb3"), dict(imitation=1.0), dict(imitation=None),
                  dict(demonstrations=0), dict(preset="paper")):
        assert resolve_config(prog, steps=2_000_000, **{"imitation": 0, **other}).sparse_imitation == 0.0, other
    assert resolve_config(prog, steps=2_000_000, algo="td3").sparse_gamma is not None  # the 8 sequences' rule


def test_a_run_with_imitation_keeps_it_across_a_resume_and_says_its_demonstrations(tiny, tmp_path, capsys):
    from conftest import asapc

    from asap_dsl.runs import RunDir

    out = tmp_path / "r"
    code, _, err = asapc(capsys, "train", tiny, "--steps", 4000, "--imitation", 1, "--no-eval", "--out", out,
                         "--envs", 2)
    assert code == 0, err
    m = RunDir(out).read_manifest()
    assert m["config"]["imitation"] == 1.0 and m["demonstrations"]["added"] > 0
    code, _, err = asapc(capsys, "train", tiny, "--steps", 4000, "--imitation", 0, "--resume", "--out", out)
    assert code != 0 and "--imitation 0.0 (the run has 1.0)" in err, err
    code, _, err = asapc(capsys, "train", tiny, "--imitation", "-1")
    assert code == 2 and "expected a number of 0 or more" in err, err


def test_where_the_actor_imitates_its_networks_are_silu_unless_the_run_chose():
    """SiLU was measured with the imitation (alone it was mixed): the default's SAC takes it where
    it imitates, and nowhere else; a run's own choice stands."""
    prog = asap_dsl.loads(RAIL, "rail.asap")
    assert resolve_config(prog).hyper["activation_fn"] == DEFAULT.imitation_activation == "silu"
    for other in (dict(imitation=0), dict(algo="td3"), dict(engine="sb3"), dict(preset="paper")):
        assert "activation_fn" not in resolve_config(prog, **other).hyper, other
    assert resolve_config(prog, settings={"activation_fn": "elu"}).hyper["activation_fn"] == "elu"
