"""What a user brings to training (issue 20): any keyword of the algorithm's constructor or policy
in a train block or ``settings=``, checked against the installed engine; observation scaling per
state entry, said where it is chosen; validation sized to the run; the gymnasium ids on
``import asap_dsl``; the oracle's ceiling from a cached prefix of the states."""

from __future__ import annotations

import inspect
import json
import subprocess
import sys

import numpy as np
import pytest

import asap_dsl
from asap_dsl.backends.rl.config import ConfigError, resolve_config
from asap_dsl.runs import RunDir
from conftest import RAIL, ROOT, asapc, one_line_error

# rl-zoo3's tuned SAC for MountainCarContinuous-v0 (hyperparams/sac.yml), as a train block.
ZOO_SAC = """
  train { algo = sac, learning_rate = 3e-4, buffer_size = 50000, batch_size = 512, ent_coef = 0.1,
          train_freq = 32, gradient_steps = 32, gamma = 0.9999, tau = 0.01, learning_starts = 0,
          use_sde = true, policy_kwargs = {log_std_init: -3.67, net_arch: [64, 64]} }
"""

FAST = {"net_arch": [16, 16], "learning_starts": 64, "batch_size": 32}


def _rail(extra: str = "", init: str = "init [-1.5, 1.5]") -> str:
    text = RAIL.replace("init [-1.5, 1.5]", init)
    return text.replace("tolerances 20, 10, 5\n", "tolerances 20, 10, 5\n" + extra)


@pytest.fixture()
def zoo(tmp_path):
    p = tmp_path / "zoo.asap"
    p.write_text(_rail(ZOO_SAC))
    return p


# ----------------------------------------------------------------------- 1. training settings
def test_the_language_knows_every_keyword_of_the_installed_algorithms():
    """The checker's table (no import of the libraries at lint time) is the installed libraries'."""
    import sbx
    import stable_baselines3 as sb3

    from asap_dsl.checker_common import HYPERPARAMETERS
    from asap_dsl.backends.rl.hyper import EXTENSIONS, keywords

    own = {"self", "policy", "env", "seed", "device", "tensorboard_log", "verbose", "_init_setup_model"}
    found = set(EXTENSIONS)
    for name, mod, algos in (("sb3", sb3, ("SAC", "TD3", "DDPG", "PPO", "A2C")), ("sbx", sbx, ("SAC", "TD3", "DDPG", "PPO"))):
        for a in algos:
            cls = getattr(mod, a)
            ctor = set(inspect.signature(cls.__init__).parameters) - own
            policy = set(inspect.signature(cls.policy_aliases["MlpPolicy"].__init__).parameters) - {
                "self", "observation_space", "action_space", "lr_schedule"}
            k = keywords(name, a.lower())  # read from the source, without importing it
            assert k.constructor - set(EXTENSIONS) == ctor and k.policy == policy, (name, a)
            found |= ctor | policy
    assert set(HYPERPARAMETERS) == found


def test_a_train_block_takes_the_rl_zoo3_settings_and_they_reach_the_model_on_both_engines(zoo, tmp_path):
    prog = asap_dsl.load(zoo)
    assert prog.task("go").model.train["policy_kwargs"] == {"log_std_init": -3.67, "net_arch": [64, 64]}
    for engine in ("sb3", "sbx"):
        cfg = resolve_config(prog, engine=engine, steps=400, n_envs=2)
        assert cfg.hyper["use_sde"] is True and cfg.hyper["log_std_init"] == -3.67 and cfg.hyper["net_arch"] == [64, 64]
        res = asap_dsl.train(prog, steps=400, n_envs=2, out=tmp_path / engine, engine=engine, evaluate=False,
                             settings={"batch_size": 32, "gradient_steps": 2})
        assert res.status == "finished"
        model = get_model(tmp_path / engine, engine)
        assert model.use_sde and model.gamma == 0.9999 and model.train_freq.frequency == 32
        assert model.batch_size == 32  # the explicit setting beats the block
        if engine == "sb3":
            assert float(model.actor.log_std.mean().detach()) == pytest.approx(-3.67, abs=0.05)  # a few updates since
        else:
            assert model.policy.use_sde


def get_model(run_dir, engine):
    from asap_dsl.backends.rl.engines import get_engine

    return get_engine(engine).load("sac", RunDir(run_dir).path / "model.zip")


def test_policy_kwargs_merge_with_the_presets_never_twice(tiny):
    prog = asap_dsl.load(tiny)
    cfg = resolve_config(prog, settings={"use_sde": True, "policy_kwargs": {"log_std_init": -3.6, "net_arch": [32, 32]}})
    assert cfg.hyper["net_arch"] == [32, 32] and cfg.hyper["log_std_init"] == -3.6  # the preset's [64, 64] replaced
    cfg = resolve_config(prog, settings={"ent_coef": "auto_0.1", "target_entropy": -2.0})
    assert "target_entropy_per_action" not in cfg.hyper  # the user's spelling replaces the preset's
    from asap_dsl.backends.rl.sb3 import model_kwargs
    from gymnasium import spaces

    kw = model_kwargs("sac", spaces.Box(-1, 1, (1,)), cfg.hyper, "sbx")
    assert kw["target_entropy"] == -2.0 and kw["ent_coef"] == "auto_0.1" and kw["policy_kwargs"] == {"net_arch": [64, 64]}


@pytest.mark.parametrize("settings, words", [
    ({"use_sdee": True}, "did you mean 'use_sde'"),
    ({"optimize_memory_usage": True}, "the sb3 engine's has it"),
    ({"n_epochs": 4}, "sac has no setting 'n_epochs' (ppo has it)"),
    ({"ent_coef": "auto_zero"}, '"auto_0.1"'),
    ({"net_arch": [16], "policy_kwargs": {"net_arch": [32]}}, "net_arch twice"),
    ({"activation_fn": "relux"}, "did you mean 'relu'"),
    ({"optimizer_class": object}, "cannot be stored in the run's manifest"),
    ({"policy_kwargs": [1]}, "must be named values"),
])
def test_a_setting_the_engine_does_not_take_is_one_sentence(tiny, settings, words):
    with pytest.raises(ConfigError) as err:
        resolve_config(asap_dsl.load(tiny), engine="sbx", settings=settings)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_a_value_the_library_refuses_is_a_config_error_not_a_traceback(tiny, tmp_path, capsys):
    with pytest.raises(ConfigError, match="refused the settings"):
        asap_dsl.train(tiny, steps=100, n_envs=2, out=tmp_path / "r", engine="sb3", settings={"train_freq": [1, "epoch"]},
                       evaluate=False)
    assert not (tmp_path / "r").exists()


def test_the_cli_says_a_misspelt_block_setting_in_one_sentence(tmp_path, capsys):
    spec = tmp_path / "s.asap"
    spec.write_text(_rail("  train { use_sdee = true }\n"))
    code, out, err = asapc(capsys, "lint", spec)
    assert code == 1 and "unknown training setting 'use_sdee'" in out + err and "did you mean 'use_sde'" in out + err
    spec.write_text(_rail("  train { optimize_memory_usage = true }\n"))
    code, out, err = asapc(capsys, "train", spec, "--steps", "100", "--out", tmp_path / "r", "--quiet")
    assert code == 2 and "the sb3 engine's has it" in one_line_error(err)


def test_a_block_for_another_algorithm_is_left_out_when_the_flag_overrides_it(tiny):
    prog = asap_dsl.loads(_rail("  train { algo = ppo, n_epochs = 3 }\n"), "rail.asap")
    assert resolve_config(prog).hyper["n_epochs"] == 3
    assert "n_epochs" not in resolve_config(prog, algo="sac").hyper


# ----------------------------------------------------------------------- 2. observation scaling
def test_an_init_range_of_zero_width_is_scaled_by_the_state_space_and_said(tmp_path, capsys):
    from asap_dsl.backends.rl.sb3 import Scaling

    spec = tmp_path / "still.asap"
    spec.write_text(_rail(init="init [0, 0]"))  # every episode starts at rest: the init box has no width
    prog = asap_dsl.load(spec)
    cfg = resolve_config(prog)
    assert cfg.observation_scaling == "init" and cfg.observation_sources == {"x": "state"}
    scaling = Scaling.for_run(prog.system, cfg, prog.task("go").model.init_box)
    assert scaling.sources == ("state",) and scaling.obs_half[0] == 2.0  # was 1: the raw entry beside scaled ones
    code, out, _ = asapc(capsys, "show", spec)
    assert code == 0 and "observe        state  (the default preset's scaling: x by the state space)" in out
    code, out, _ = asapc(capsys, "show", "--format", "json", spec)
    assert json.loads(out)["tasks"]["go"]["observation_scaling"]["entries"] == {"x": "state"}


def test_observe_scaling_chooses_the_box_and_the_manifest_records_it(tmp_path, tiny):
    prog = asap_dsl.loads(_rail().replace("deadline 20", "deadline 20\n  observe state, time, scaling = none"), "rail.asap")
    cfg = resolve_config(prog)
    assert prog.task("go").model.observe == ("state", "time") and cfg.observation_scaling == "none"
    assert cfg.observation_sources == {"x": "none"}
    assert resolve_config(prog, preset="paper").observation_scaling == "none"
    res = asap_dsl.train(tiny, steps=64, n_envs=2, out=tmp_path / "r", settings=FAST, evaluate=False, engine="sb3")
    assert RunDir(res.run_dir).read_manifest()["config"]["observation_sources"] == {"x": "init"}


def test_a_run_from_before_the_per_entry_rule_keeps_its_own_scaling(tmp_path):
    from asap_dsl.backends.rl.config import TrainConfig
    from asap_dsl.backends.rl.sb3 import Scaling

    prog = asap_dsl.loads(_rail(init="init [0, 0]"), "still.asap")
    old = resolve_config(prog).to_dict()
    del old["observation_sources"]  # a manifest written before it was recorded
    cfg = TrainConfig.from_dict(old)
    assert cfg.observation_sources is None
    assert Scaling.for_run(prog.system, cfg, None).sources == ("none",)  # the entry stayed raw then


@pytest.mark.parametrize("clause, words", [("observe state, scalin = init", "did you mean 'scaling'"),
                                           ("observe state, scaling = sate", "did you mean 'state'"),
                                           ("scaling = init", "write `observe state, scaling = init`")])
def test_a_wrong_observe_scaling_is_one_diagnostic(clause, words):
    from conftest import diagnostics

    ds = diagnostics(_rail().replace("deadline 20", "deadline 20\n  " + clause))
    assert len(ds) == 1 and words in (ds[0].message + " " + (ds[0].hint or ""))
