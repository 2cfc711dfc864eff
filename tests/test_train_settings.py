"""What a user brings to training (issue 20): any keyword of the algorithm's constructor or policy
in a train block or ``settings=``, checked against the installed engine; observation scaling per
state entry, said where it is chosen; validation sized to the run; the gymnasium ids on
``import asap_dsl``; the oracle's ceiling from a cached prefix of the states."""

from __future__ import annotations

import importlib.util
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
    from asap_dsl.backends.rl.hyper import EXTENSIONS, POLICY_EXTENSIONS, keywords

    own = {"self", "policy", "env", "seed", "device", "tensorboard_log", "verbose", "_init_setup_model"}
    found = set(EXTENSIONS)
    for name, mod, algos in (("sb3", sb3, ("SAC", "TD3", "DDPG", "PPO", "A2C")), ("sbx", sbx, ("SAC", "TD3", "DDPG", "PPO"))):
        for a in algos:
            cls = getattr(mod, a)
            ctor = set(inspect.signature(cls.__init__).parameters) - own
            policy = set(inspect.signature(cls.policy_aliases["MlpPolicy"].__init__).parameters) - {
                "self", "observation_space", "action_space", "lr_schedule"}
            k = keywords(name, a.lower())  # read from the source, without importing it
            added = POLICY_EXTENSIONS.get((name, a.lower()), frozenset())
            assert k.constructor - set(EXTENSIONS) == ctor and k.policy - added == policy, (name, a)
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
    assert kw["target_entropy"] == -2.0 and kw["ent_coef"] == "auto_0.1"
    import flax.linen as nn

    assert kw["policy_kwargs"] == {"net_arch": [64, 64], "activation_fn": nn.silu}  # the preset's, once each


@pytest.mark.parametrize("settings, words", [
    ({"use_sdee": True}, "did you mean 'use_sde'"),
    ({"optimize_memory_usage": True}, "the sb3 engine's has it"),
    ({"n_epochs": 4}, "sac has no setting 'n_epochs' (ppo has it)"),
    ({"ent_coef": "auto_zero"}, '"auto_0.1"'),
    ({"net_arch": [16], "policy_kwargs": {"net_arch": [32]}}, "net_arch twice"),
    ({"activation_fn": "relux"}, "did you mean 'relu'"),
    ({"optimizer_class": object}, "cannot be stored in the run's manifest"),
    ({"policy_kwargs": [1]}, "must be named values"),
    ({"net_arch": [0]}, "positive whole numbers"),  # was a ZeroDivisionError inside JAX's initialiser
    ({"net_arch": {"pi": [64, 64], "qf": [64, -1]}}, "positive whole numbers"),
    ({"net_arch": [100_000, 100_000]}, "use narrower layers"),  # was JAX out of memory (40 GB)
    ({"gamma": 2}, "'gamma' must be a number from 0 to 1, not 2"),  # trained on silently
    ({"batch_size": 0}, "'batch_size' must be a whole number, 1 or more"),
    ({"learning_rate": "nan"}, "'learning_rate' takes a number above 0"),
    ({"tau": 0}, "'tau' must be a number in (0, 1]"),
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


@pytest.mark.parametrize("block, words", [
    ("gamma = 2", "'gamma' must be a number from 0 to 1, not 2"),
    ("batch_size = 0", "'batch_size' must be a whole number, 1 or more, not 0"),
    ("n_envs = 0", "'n_envs' must be a whole number, 1 or more, not 0"),
    ("learning_rate = nan", "'learning_rate' takes a number above 0, not 'nan'"),
    ("seed = 1e30", "'seed' must be a whole number from 0 to 4,294,967,295"),
    ("seed = 1, seed = 2", "'seed' is given twice in the train block"),
    ("gradient_steps = -2", "'gradient_steps' must be a whole number, -1 or more"),
])
def test_lint_checks_the_numbers_of_a_train_block(block, words):
    """Found by the hostile review: each of these was lint-clean (γ = 2 and a batch of 0 trained
    on, or failed inside the library)."""
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(_rail(f"  train {{ {block} }}\n"))
    assert [d.code for d in info.value.diagnostics] == ["E117"] and words in info.value.diagnostics[0].message
    for fine in ("gamma = 1, gradient_steps = -1, sde_sample_freq = -1, ent_coef = \"auto_0.1\", train_freq = [1, \"episode\"]",
                 "tau = 1, learning_starts = 0, seed = 4294967295"):
        asap_dsl.loads(_rail(f"  train {{ {fine} }}\n"))


def test_a_reward_setting_given_twice_is_one_diagnostic():
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(_rail("  reward rho(window = 1, window = 2)\n"))
    assert [d.code for d in info.value.diagnostics] == ["E117"] and "'window' twice" in info.value.diagnostics[0].message


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


# ----------------------------------------------------------------------- 3. validation scaled to the run
def test_a_short_run_validates_on_fewer_states():
    from asap_dsl.backends.rl.validation import validation_states

    prog = asap_dsl.loads(RAIL, "rail.asap")
    assert resolve_config(prog, steps=2000).validation_episodes == 100  # was 500 whatever the length
    assert resolve_config(prog, steps=250_000).validation_episodes == 500
    assert validation_states(10_000, 500) == 200


def test_a_validation_waits_while_validation_has_stepped_more_than_training():
    from asap_dsl.backends.rl.validation import Schedule

    s = Schedule(every=64, cost=100)  # e.g. 10 states of an episode of at most 10 steps
    assert not s.due(63, 0.5) and s.due(64, 1.0)  # the first due one always runs
    s.done(64, 3.0, cost=2.0)
    assert s.next_step == 128
    assert not s.due(128, 4.0)   # two validations step 200 states: more than 128 training steps
    assert not s.due(199, 1e6)   # ... whatever the clock says: a run is the same on every machine
    assert s.due(200, 4.5)
    restored = Schedule(every=64, cost=100)
    restored.restore(s.to_dict(), validations=5)
    assert (restored.count, restored.spent, restored.last, restored.next_step) == (1, 2.0, 2.0, 128)
    old = {k: v for k, v in s.to_dict().items() if k != "validations"}  # a checkpoint from before the count
    restored.restore(old, validations=1)
    assert restored.count == 1 and not restored.due(199, 9.0)


class _Notes:
    def __init__(self):
        self.lines, self.rows = [], []

    def start(self, config, done, ceiling): pass
    def advance(self, done): pass
    def validated(self, row): self.rows.append(row)
    def finish(self): pass
    def note(self, line): self.lines.append(line)


def test_tensorboard_has_sb3s_rollout_means_beside_the_validations_at_the_curves_steps(tiny, tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    notes = _Notes()
    res = asap_dsl.train(tiny, steps=600, n_envs=2, out=tmp_path / "r", settings=FAST, evaluate=False, engine="sb3",
                         progress=notes)
    assert any(line.startswith("validation: 100 states, up to 30 times, each only while validation's steps stay "
                                   "within 1x training's")
               for line in notes.lines)
    assert any(line.startswith(f"validation: {len(res.curves)} times, ") for line in notes.lines)
    (events,) = (tmp_path / "r" / "tb").iterdir()
    ea = EventAccumulator(str(events))
    ea.Reload()
    steps = lambda tag: [e.step for e in ea.Scalars(tag)]  # noqa: E731
    curves = [r["steps"] for r in res.curves]
    assert steps("validation/score") == curves
    done = curves[1:]  # after the first episodes have ended (none has by the first validation)
    assert set(done) <= set(steps("rollout/ep_rew_mean")) and set(done) <= set(steps("rollout/ep_len_mean"))
    fps = steps("time/fps")
    assert fps and len(fps) == len(set(fps))  # once per dump


UNREACHABLE = RAIL.replace("ode { x' = 2 * u }", "ode { x' = 0.01 * u }").replace("init [-1.5, 1.5]", "init [-1.5, -1]")


def test_when_no_validation_succeeds_the_latest_model_is_kept_and_said(tmp_path, capsys):
    spec = tmp_path / "far.asap"
    spec.write_text(UNREACHABLE)  # the goal is 2 m away at 0.01 m/s: never reached
    code, out, err = asapc(capsys, "train", spec, "--steps", "300", "--envs", "2", "--engine", "sb3", "--out",
                           tmp_path / "r", "--no-eval", "--quiet")
    assert code == 0, err
    manifest = RunDir(tmp_path / "r").read_manifest()
    curves = (tmp_path / "r" / "curves.csv").read_text().splitlines()[1:]
    assert len(curves) > 1 and manifest["best"]["steps"] == int(curves[-1].split(",")[0])  # the latest, not the first
    assert "no validation succeeded" in out and "model.zip is the latest policy" in out


# ----------------------------------------------------------------------- 5. the ceiling from a cached prefix
def test_the_seeded_draw_is_a_prefix_except_where_a_state_was_redrawn_out_of_avoid():
    from asap_dsl.sampling import task_states

    prog = asap_dsl.loads(RAIL, "rail.asap")
    task = prog.task("go").model
    assert np.array_equal(task_states(prog.system, task, 20, seed=2024), task_states(prog.system, task, 200, seed=2024)[:20])
    # an avoid region over part of the init box: the states drawn into it are redrawn after the
    # whole first draw, so the first 20 of 200 are not the 20 (the cache compares state by state)
    risky = asap_dsl.loads(RAIL.replace("box(x in [-2, -1.8])", "box(x in [-1.5, -0.5])"), "risky.asap")
    t = risky.task("go").model
    assert not np.array_equal(task_states(risky.system, t, 20, seed=2024), task_states(risky.system, t, 200, seed=2024)[:20])


@pytest.fixture()
def trained(tiny, tmp_path):
    asap_dsl.train(tiny, steps=64, n_envs=2, out=tmp_path / "run", settings=FAST, evaluate=False, engine="sb3")
    return tmp_path / "run"


def test_eval_takes_the_ceiling_from_a_cached_oracle_on_the_first_states(tiny, trained, capsys, tmp_path,
                                                                         monkeypatch):
    # a cache of this test's own: another test of the session may have solved the same spec
    monkeypatch.setenv("ASAP_CACHE_DIR", str(tmp_path / "cache"))
    code, out, err = asapc(capsys, "eval", trained, "--episodes", "12", "--no-oracle")
    assert code == 0 and "not computed for these 12 states" in out and "--episodes 12` computes it" in out
    assert asapc(capsys, "oracle", tiny, "--episodes", "8", "--workers", "1")[0] == 0
    code, out, err = asapc(capsys, "eval", trained, "--episodes", "12", "--no-oracle", "--format", "json", "--states")
    ev = json.loads(out)
    assert ev["oracle"]["states"] == 8 and ev["rows"][0]["ceiling"]["states"] == 8  # the 8 cached are the first 12's
    # the distance below the ceiling is the policy's rate on the same 8 states, not on all 12
    t_reach = ev["per_state"]["t_reach"]
    for row in ev["rows"]:
        on_eight = sum(t is not None and t <= row["tolerance"] for t in t_reach[:8]) / 8
        assert row["rate_on_ceiling_states"] == pytest.approx(on_eight)
    code, out, err = asapc(capsys, "eval", trained, "--episodes", "12", "--no-oracle")
    assert "the oracle's on the first 8 of these 12 states, and the distance below it" in out
    row = ev["rows"][0]
    below = 100 * (row["ceiling"]["rate"] - row["rate_on_ceiling_states"])
    first_row = next(line for line in out.splitlines() if line.split()[:1] == [str(row["tolerance"])])
    assert first_row.endswith(f"{below:.1f} pts")
    code, out, err = asapc(capsys, "eval", trained, "--episodes", "5", "--no-oracle", "--format", "json")
    assert json.loads(out)["oracle"]["states"] == 5  # the first 5 of the 8: exact


def test_eval_says_it_computes_the_oracle_and_shows_its_progress(trained, capsys):
    # a seed of its own: the cache is the test session's
    code, out, err = asapc(capsys, "eval", trained, "--episodes", "3", "--workers", "1", "--seed", "31")
    assert code == 0 and "computing the oracle's ceiling on 3 states (not cached" in err
    again = asapc(capsys, "eval", trained, "--episodes", "3", "--no-oracle", "--format", "json", "--seed", "31")
    assert json.loads(again[1])["oracle"]["states"] == 3 and "computing" not in again[2]


def test_trains_final_evaluation_finds_a_cached_oracle_of_fewer_states(tmp_path, capsys):
    own = tmp_path / "own.asap"
    own.write_text(RAIL + "# a spec of its own: the cache is the session's\n")
    assert asapc(capsys, "oracle", own, "--episodes", "6", "--workers", "1")[0] == 0
    res = asap_dsl.train(own, steps=64, n_envs=2, out=tmp_path / "r", settings=FAST, eval_episodes=10, engine="sb3")
    assert res.evaluation.oracle["states"] == 6 and "ceiling: not computed" not in res.evaluation.render()


# ----------------------------------------------------------------------- 4. gymnasium ids
def test_import_asap_dsl_registers_the_benchmark_ids_without_importing_gymnasium():
    code = ("import sys, asap_dsl; assert 'gymnasium' not in sys.modules; import gymnasium; "
            "env = gymnasium.make('asap/dc_motor-reach_avoid-v0'); print(env.reset(seed=0)[0].shape); "
            "assert 'asap/swimmer-reach-v0' in gymnasium.registry")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd="/", timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == "(3,)", out.stderr
    # gymnasium first, then asap_dsl (as rl_zoo3's --gym-packages does), and gymnasium's module prefix
    code = ("import gymnasium; env = gymnasium.make('asap_dsl:asap/bicycle-reach-v0'); "
            "import asap_dsl; print(env.observation_space.shape)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd="/", timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == "(4,)", out.stderr


def test_register_a_users_own_spec(tmp_path):
    import gymnasium

    spec = tmp_path / "my_plant.asap"
    spec.write_text(RAIL)
    assert asap_dsl.register(spec) == ["asap/my_plant-go-v0"]
    assert asap_dsl.register(spec, "go", id="mine/Rail-v1", reward="rho") == ["mine/Rail-v1"]
    assert gymnasium.registry["mine/Rail-v1"].kwargs["reward"] == "rho"  # given to every make
    gymnasium.make("mine/Rail-v1")
    obs, _ = gymnasium.make("asap/my_plant-go-v0").reset(seed=1)
    assert obs.shape == (1,)
    (tmp_path / "broken.asap").write_text("system {")
    with pytest.raises(asap_dsl.SpecError):
        asap_dsl.register(tmp_path / "broken.asap")


@pytest.mark.skipif(importlib.util.find_spec("rl_zoo3") is None, reason="rl_zoo3 is not installed (pip install rl_zoo3)")
def test_rl_zoo3_trains_a_benchmark_id_with_gym_packages(tmp_path):
    out = subprocess.run([sys.executable, "-m", "rl_zoo3.train", "--algo", "sac", "--env", "asap/dc_motor-reach_avoid-v0",
                          "--gym-packages", "asap_dsl", "-n", "300", "--eval-freq", "-1", "-f", str(tmp_path / "logs")],
                         capture_output=True, text=True, timeout=900, cwd=tmp_path,
                         env={**__import__("os").environ, "OMP_NUM_THREADS": "1"})
    assert out.returncode == 0, out.stderr[-2000:]
    assert list((tmp_path / "logs" / "sac").glob("asap-dc_motor-reach_avoid-v0_*/asap-dc_motor-reach_avoid-v0.zip"))


def test_the_progress_says_whose_ceiling_it_shows_beside_validation():
    """The ceiling beside a validation is the evaluation states' (the cached oracle's), not the
    validation states': the progress says so once, and only when it shows one."""
    import io
    from types import SimpleNamespace

    from asap_dsl.cli.train import ConsoleProgress

    cfg = SimpleNamespace(task="go", algo="sac", reward="asap", preset="default", seed=0, steps=100, n_envs=2,
                          engine="sbx")
    shown, plain = io.StringIO(), io.StringIO()
    ConsoleProgress(shown).start(cfg, 0, {30: 0.99})
    ConsoleProgress(plain).start(cfg, 0, None)
    assert "the oracle's on the evaluation states, not on validation's" in shown.getvalue()
    assert "evaluation states" not in plain.getvalue()
    resumed = io.StringIO()
    ConsoleProgress(resumed).start(cfg, 50, {30: 0.99})
    head, whose = resumed.getvalue().splitlines()
    assert head.endswith("resuming at 50") and whose.strip().startswith("the ceiling beside each validation")
