"""Training engines: sbx (JAX) and stable-baselines3 (torch) train every algorithm each has through
the same run directory, checkpoints, ``--resume`` and ``asapc eval``; a JAX run stopped by SIGTERM
resumes from its step with its keys; a run of one engine is not resumed by the other; both build
the same networks on the same scaled spaces; and JAX stays unloaded where nothing trains."""

from __future__ import annotations

import json
import os
import pickle
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import asap_dsl
from asap_dsl.checker_common import ALGORITHMS
from asap_dsl.runs import RunDir
from conftest import RAIL, asapc, completed, one_line_error

ROOT = Path(__file__).resolve().parents[1]

# Gradient steps within a few hundred environment steps, through the spec (the CLI has no
# hyperparameter flags); n_steps is the rollout of PPO/A2C but the n-step return of the others.
BLOCK = {"off": "train { learning_starts = 64, batch_size = 32 }", "on": "train { n_steps = 32, batch_size = 32 }"}


def _pairs():
    from asap_dsl.backends.rl.engines import ENGINES, get_engine

    return [(e, a) for e in ENGINES for a in ALGORITHMS if get_engine(e).runs(a)]


def _spec(tmp_path: Path, algo: str) -> Path:
    kind = "on" if algo in ("ppo", "a2c") else "off"
    p = tmp_path / f"rail_{kind}.asap"
    p.write_text(RAIL.replace("tolerances 20, 10, 5", "tolerances 20, 10, 5\n  " + BLOCK[kind]))
    return p


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("ASAP_CACHE_DIR", str(tmp_path / "cache"))


def _load(engine: str, algo: str, path: Path):
    from asap_dsl.backends.rl.engines import get_engine

    return get_engine(engine).load(algo, path)


@pytest.mark.parametrize("engine, algo", _pairs())
def test_every_algorithm_trains_and_evaluates_on_each_engine_that_has_it(tmp_path, capsys, monkeypatch, engine, algo):
    from dataclasses import replace

    from asap_dsl.backends.rl import presets

    # PPO's first update comes after 512 steps; the plateau rule may end so short a run before it.
    monkeypatch.setitem(presets.PRESETS, "default", replace(presets.DEFAULT, plateau=None))
    spec, out = _spec(tmp_path, algo), tmp_path / "run"
    code, _, err = asapc(capsys, "train", spec, "--algo", algo, "--engine", engine, "--steps", 300, "--envs", 2,
                        "--out", out, "--quiet", "--no-eval")
    assert code == 0, err
    manifest = RunDir(out).read_manifest()
    assert (manifest["config"]["engine"], manifest["config"]["algo"], manifest["status"]) == (engine, algo, "finished")
    assert (out / "checkpoint" / "replay.pkl").is_file() == (algo not in ("ppo", "a2c"))
    model = _load(engine, algo, out / "checkpoint" / "model.zip")
    assert model.num_timesteps >= 300 and model._n_updates > 0  # it learned, not only stepped
    code, text, err = asapc(capsys, "eval", out, "--no-oracle", "--episodes", 30, "--format", "json")
    assert code == 0, err
    ev = json.loads(text)
    assert ev["episodes"] == 30 and [r["tolerance"] for r in ev["rows"]] == [20, 10, 5]


def test_an_engine_without_the_algorithm_is_one_sentence(tiny, tmp_path, capsys):
    code, _, err = asapc(capsys, "train", tiny, "--algo", "a2c", "--engine", "sbx", "--out", tmp_path / "r", "--quiet")
    line = one_line_error(err)
    assert code == 2 and "the sbx engine has no a2c" in line and "sb3" in line, line
    assert not (tmp_path / "r" / "run.json").exists()
    code, _, err = asapc(capsys, "train", tiny, "--engine", "jax", "--out", tmp_path / "r", "--quiet")
    assert code == 2 and "invalid choice" in err.strip().splitlines()[-1]


def test_the_default_preset_trains_on_sbx_where_it_has_the_algorithm(tiny):
    from asap_dsl.backends.rl.config import ConfigError, TrainConfig, resolve_config

    prog = asap_dsl.load(tiny)
    for algo in ALGORITHMS:
        assert resolve_config(prog, algo=algo).engine == ("sb3" if algo == "a2c" else "sbx"), algo
        assert resolve_config(prog, algo=algo, preset="paper").engine == "sb3", algo
        assert resolve_config(prog, algo=algo, engine="sb3").engine == "sb3", algo
    assert resolve_config(prog, preset="paper", engine="sbx").engine == "sbx"
    with pytest.raises(ConfigError, match="unknown engine 'torch'"):
        resolve_config(prog, engine="torch")
    # a run recorded before engines existed was trained by stable-baselines3
    old = resolve_config(prog).to_dict()
    del old["engine"]
    assert TrainConfig.from_dict(old).engine == "sb3"


def test_a_run_of_one_engine_is_not_resumed_by_the_other(tmp_path, capsys):
    spec = _spec(tmp_path, "sac")
    for engine, other in (("sbx", "sb3"), ("sb3", "sbx")):
        out = tmp_path / engine
        asap_dsl.train(spec, engine=engine, steps=200, n_envs=2, out=out, evaluate=False)
        before = (out / "run.json").read_text()
        code, _, err = asapc(capsys, "train", spec, "--out", out, "--resume", "--engine", other, "--steps", 300,
                             "--quiet")
        line = one_line_error(err)
        assert code == 1 and f"--engine {other} (the run has {engine})" in line, line
        assert (out / "run.json").read_text() == before
        # without --engine, --resume continues on the run's own engine
        res = asap_dsl.train(spec, out=out, resume=True, steps=300, evaluate=False)
        assert res.config.engine == engine and completed(res, 300)


def _read_lines(stream, lines: list) -> None:
    for line in stream:
        lines.append(line)


def test_sigterm_on_the_jax_engine_checkpoints_and_resume_continues_from_that_step(tmp_path):
    spec, out = _spec(tmp_path, "sac"), tmp_path / "run"
    cmd = [sys.executable, "-m", "asap_dsl.cli", "train", str(spec), "--engine", "sbx", "--steps", "30000",
           "--envs", "2", "--out", str(out), "--no-eval"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONUNBUFFERED="1"))
    lines: list[str] = []
    reader = threading.Thread(target=_read_lines, args=(proc.stderr, lines), daemon=True)
    reader.start()
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None and not any("validation at" in x for x in lines):
        time.sleep(0.1)  # the first validation: compiled, and well into gradient steps
    assert any("validation at" in x for x in lines), "".join(lines)
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=120)
    reader.join(timeout=10)
    err = "".join(lines)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "--resume" in err and "sbx engine" in err
    manifest = RunDir(out).read_manifest()
    assert manifest["status"] == "interrupted" and manifest["config"]["engine"] == "sbx"
    stopped_at = manifest["steps_done"]
    state = json.loads((out / "checkpoint" / "state.json").read_text())
    assert 1000 <= state["steps"] == stopped_at < 30000
    assert _load("sbx", "sac", out / "checkpoint" / "model.zip").num_timesteps == stopped_at
    curves_before = (out / "curves.csv").read_text().splitlines()
    res = asap_dsl.train(spec, out=out, resume=True, steps=stopped_at + 400, evaluate=False)
    assert res.status == "finished" and res.config.engine == "sbx"
    assert stopped_at + 400 <= res.steps <= stopped_at + 400 + 2
    curves_after = (out / "curves.csv").read_text().splitlines()
    assert curves_after[: len(curves_before)] == curves_before
    assert min(int(x.split(",")[0]) for x in curves_after[len(curves_before):]) > stopped_at


def test_a_checkpoint_restores_the_jax_keys_and_the_random_actions(tmp_path):
    import jax

    from asap_dsl.backends.rl.config import TrainConfig
    from asap_dsl.backends.rl.session import Session

    spec, out = _spec(tmp_path, "sac"), tmp_path / "run"
    asap_dsl.train(spec, engine="sbx", steps=300, n_envs=2, out=out, evaluate=False, seed=3)
    run = RunDir(out)
    ckpt = run.checkpoint()
    with open(ckpt.path("state.pkl"), "rb") as f:
        rng = pickle.load(f)["rng"]
    keys = rng["jax"]
    assert not np.array_equal(keys["model"], np.asarray(jax.random.PRNGKey(3)))  # it moved on from the seed
    cfg = TrainConfig.from_dict(run.read_manifest()["config"])
    model = Session(asap_dsl.load(spec), cfg, run, None).restore(ckpt)  # loading re-seeds; restoring re-sets
    assert np.array_equal(np.asarray(model.key), keys["model"])
    assert np.array_equal(np.asarray(model.policy.key), keys["policy"])
    assert np.array_equal(np.asarray(model.policy.noise_key), keys["noise"])
    assert model.action_space.np_random.bit_generator.state == rng["actions"]


def _param_count(tree) -> int:
    import jax

    return int(sum(np.prod(x.shape) for x in jax.tree_util.tree_leaves(tree)))


@pytest.mark.parametrize("algo", ["sac", "td3", "ddpg", "ppo"])
def test_both_engines_build_the_same_networks_on_the_same_spaces(algo):
    from asap_dsl.backends.rl.config import resolve_config
    from asap_dsl.backends.rl.session import LearnerEnv
    from asap_dsl.backends.rl.engines import get_engine
    from asap_dsl.backends.rl.sb3 import Scaling, ScaledVecEnv
    from asap_dsl.env import make_vec_env

    prog = asap_dsl.load(ROOT / "specs" / "dc_motor.asap")
    cfg = resolve_config(prog, "reach_avoid", algo=algo)
    task = prog.task("reach_avoid").model
    scaling = Scaling.for_system(prog.system, cfg.observation_scaling, cfg.action_scaling, task.init_box)
    env = LearnerEnv(ScaledVecEnv(make_vec_env(prog, "reach_avoid", num_envs=cfg.n_envs, seed=0), scaling), False)
    sbx, sb3 = (get_engine(e).build(algo, env, cfg.hyper, 0) for e in ("sbx", "sb3"))
    for a, b in ((sbx.observation_space, sb3.observation_space), (sbx.action_space, sb3.action_space)):
        assert np.array_equal(a.low, b.low) and np.array_equal(a.high, b.high)
    assert np.all(sbx.action_space.low == -1) and np.all(sbx.action_space.high == 1)
    for name in ("learning_rate", "gamma", "batch_size", "n_steps", "tau", "learning_starts", "buffer_size",
                 "gae_lambda", "n_epochs", "vf_coef", "max_grad_norm"):
        assert getattr(sbx, name, None) == getattr(sb3, name, None), name
    m = prog.system.n_action
    torch_count = lambda net: sum(p.numel() for p in net.parameters())  # noqa: E731
    if algo == "ppo":
        assert _param_count(sbx.policy.actor_state.params) + _param_count(sbx.policy.vf_state.params) \
            == torch_count(sb3.policy)
        return
    assert _param_count(sbx.policy.actor_state.params) == torch_count(sb3.actor)
    assert _param_count(sbx.policy.qf_state.params) == torch_count(sb3.critic)
    if algo == "sac":
        assert sbx.target_entropy == sb3.target_entropy == -3.0 * m
    else:
        assert np.allclose(sbx.action_noise._sigma, sb3.action_noise._sigma)
    if algo == "ddpg":
        assert sbx.qf_learning_rate == cfg.hyper["learning_rate"]  # one rate for actor and critic, as in SB3


@pytest.mark.parametrize("algo", ["sac", "td3", "ddpg"])
def test_layer_normalised_critics_are_the_same_networks_on_both_engines(tmp_path, algo):
    """``layer_norm``: sbx's option, which stable-baselines3 lacks; the project's torch policies
    build the same critics (Linear, LayerNorm, activation), and a saved model loads with them."""
    import torch

    from asap_dsl.backends.rl.config import resolve_config
    from asap_dsl.backends.rl.engines import get_engine
    from asap_dsl.backends.rl.session import LearnerEnv
    from asap_dsl.backends.rl.sb3 import Scaling, ScaledVecEnv
    from asap_dsl.env import make_vec_env

    prog = asap_dsl.load(ROOT / "specs" / "dc_motor.asap")
    cfg = resolve_config(prog, "reach_avoid", algo=algo, settings={"layer_norm": True})
    task = prog.task("reach_avoid").model
    scaling = Scaling.for_system(prog.system, cfg.observation_scaling, cfg.action_scaling, task.init_box)
    env = LearnerEnv(ScaledVecEnv(make_vec_env(prog, "reach_avoid", num_envs=cfg.n_envs, seed=0), scaling), False)
    sbx, sb3 = (get_engine(e).build(algo, env, cfg.hyper, 0) for e in ("sbx", "sb3"))
    plain = get_engine("sb3").build(algo, env, {**cfg.hyper, "layer_norm": False}, 0)
    assert type(plain.policy).__name__ in ("SACPolicy", "TD3Policy")  # false: the library's own policy
    torch_count = lambda net: sum(p.numel() for p in net.parameters())  # noqa: E731
    assert _param_count(sbx.policy.qf_state.params) == torch_count(sb3.critic) > torch_count(plain.critic)
    for critic in (sb3.critic, sb3.critic_target):
        kinds = [type(m).__name__ for m in critic.qf0]
        act = "SiLU" if algo == "sac" else "ReLU"  # the default preset's SAC is SiLU
        assert kinds == ["Linear", "LayerNorm", act, "Linear", "LayerNorm", act, "Linear"]
    assert not any(isinstance(m, torch.nn.LayerNorm) for m in sb3.actor.modules())  # the critics only, as sbx
    sb3.save(str(tmp_path / "model.zip"))
    back = get_engine("sb3").load(algo, tmp_path / "model.zip")
    assert type(back.policy).__name__ == ("LayerNormSACPolicy" if algo == "sac" else "LayerNormTD3Policy")
    assert [type(m).__name__ for m in back.critic.qf0] == kinds
    for a, b in zip(sb3.critic.parameters(), back.critic.parameters()):
        assert torch.equal(a, b)


def test_jax_loads_only_to_train_on_cpu_with_one_compute_thread_and_a_disk_cache(tmp_path):
    code = f"""
import os, sys
from pathlib import Path
from asap_dsl import cli
spec = {str(ROOT / "specs" / "dc_motor.asap")!r}
assert cli.main(["lint", spec]) == 0 and cli.main(["show", spec]) == 0
import asap_dsl
from asap_dsl.backends.rl.config import resolve_config
resolve_config(asap_dsl.load(spec), "reach_avoid")
assert not {{"jax", "sbx", "flax"}} & set(sys.modules), sorted({{"jax", "sbx", "flax"}} & set(sys.modules))
from asap_dsl.backends.rl.engines import get_engine
get_engine("sbx")._model_class("sac")
import jax
assert "--xla_cpu_multi_thread_eigen=false" in os.environ["XLA_FLAGS"]
assert {{d.platform for d in jax.devices()}} == {{"cpu"}}
jax.jit(lambda x: 2 * x + 1)(1.0)  # compiled once per machine: kept in the project's cache directory
assert any(p.name.startswith("jit_") for p in (Path(os.environ["ASAP_CACHE_DIR"]) / "jax").iterdir())
print("ok")
"""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("XLA_", "JAX_"))}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env,
                       cwd=str(tmp_path))
    assert r.returncode == 0 and r.stdout.strip().endswith("ok"), r.stderr


def test_an_unusable_cache_directory_leaves_jax_without_a_disk_cache(tmp_path):
    """Found by the hostile review: with $ASAP_CACHE_DIR a file, JAX warned (with its source
    path) on every compile; now its programs are compiled each time, silently."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    code = ("import os; from asap_dsl.backends.rl.engines import _configure_jax; _configure_jax(); "
            "print(os.environ.get('JAX_COMPILATION_CACHE_DIR'))")
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    for cache, expected in ((blocker, "None"), (tmp_path / "cache", str(tmp_path / "cache" / "jax"))):
        out = subprocess.run([sys.executable, "-c", code], env=dict(env, ASAP_CACHE_DIR=str(cache)), capture_output=True,
                             text=True, check=True).stdout.strip()
        assert out == expected
