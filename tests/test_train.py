"""Training and evaluation: every algorithm trains end to end, runs resume after SIGTERM with the
same step count, evaluation is deterministic, and every bad flag or run directory gets one line."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import asap_dsl
from asap_dsl.checker_common import ALGORITHMS
from asap_dsl.runs import RunDir
from conftest import RAIL, asapc, completed, one_line_error

# A one-dimensional plant: fast to simulate and to learn something on.
TINY = RAIL

FAST = {"net_arch": [16, 16], "learning_starts": 64, "batch_size": 32}


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("ASAP_CACHE_DIR", str(tmp_path / "cache"))


def _settings(algo):
    if algo in ("ppo", "a2c"):
        return {"net_arch": [16, 16], "n_steps": 32}
    return dict(FAST)


def test_presets_cover_every_algorithm_of_the_language():
    from asap_dsl.backends.rl.presets import OFF_POLICY, PRESETS

    for p in PRESETS.values():
        assert set(p.algos) == set(ALGORITHMS) and p.algo in ALGORITHMS, p.name
    assert set(OFF_POLICY) <= set(ALGORITHMS)


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_each_algorithm_trains_and_evaluates(tiny, tmp_path, algo):
    out = tmp_path / "run"
    res = asap_dsl.train(tiny, algo=algo, steps=300, n_envs=2, out=out, settings=_settings(algo), eval_episodes=50)
    assert completed(res, 300)
    run = RunDir(out)
    manifest = run.read_manifest()
    assert manifest["status"] == "finished" and manifest["steps_done"] == res.steps
    assert manifest["config"]["algo"] == algo and manifest["spec_hash"] == asap_dsl.runs.spec_hash(TINY)
    for f in ("spec.asap", "model.zip", "curves.csv", "eval.json", "checkpoint/model.zip", "checkpoint/state.json"):
        assert (out / f).is_file(), f
    assert (out / "tb").is_dir()
    assert run.spec_path.read_text() == TINY
    ev = json.loads((out / "eval.json").read_text())
    assert ev["episodes"] == 50 and ev["seed"] == 2024
    assert [r["tolerance"] for r in ev["rows"]] == [20, 10, 5]
    for r in ev["rows"]:
        assert 0.0 <= r["rate"] <= 1.0 and r["ci95"][0] <= r["rate"] <= r["ci95"][1]
    rates = [r["rate"] for r in ev["rows"]]
    assert rates == sorted(rates, reverse=True)  # success within 20 includes success within 5
    header = (out / "curves.csv").read_text().splitlines()[0]
    assert header == "steps,seconds,score,best,success_5,success_10,success_20,return"


def test_rail_is_learned(tiny, tmp_path):
    """Not only runs: a few thousand SAC steps reach the goal from most states."""
    res = asap_dsl.train(tiny, steps=6000, n_envs=4, out=tmp_path / "r", settings={"net_arch": [32, 32], "learning_starts": 200},
                         eval_episodes=200, seed=3)
    assert res.evaluation.rate(20) > 0.8, res.evaluation.render()


def test_evaluation_is_deterministic_for_a_seed(tiny, tmp_path):
    out = tmp_path / "run"
    asap_dsl.train(tiny, steps=300, n_envs=2, out=out, settings=FAST, evaluate=False)
    a = asap_dsl.evaluate(out, episodes=100, seed=11, oracle="off")
    b = asap_dsl.evaluate(out, episodes=100, seed=11, oracle="off")
    c = asap_dsl.evaluate(out, episodes=100, seed=12, oracle="off")
    assert a.per_state == b.per_state and a.rows == b.rows
    assert a.per_state["t_reach"] != c.per_state["t_reach"] or a.rows != c.rows
    assert not (out / "eval.json").exists()  # not the run's own evaluation (seed 11): printed, not stored


def test_eval_reports_the_oracle_ceiling_and_gap(tiny, tmp_path):
    out = tmp_path / "run"
    asap_dsl.train(tiny, steps=300, n_envs=2, out=out, settings=FAST, evaluate=False)
    ev = asap_dsl.evaluate(out, episodes=40, oracle="auto", workers=1)
    assert ev.oracle["bound"] == "oracle (exact)" or ev.oracle["bound"] == "oracle (local)"
    for r in ev.rows:
        assert r["ceiling"]["states"] == 40
    # the policy never beats the physical limit on a state the oracle solved exactly
    t = np.array([np.inf if x is None else x for x in ev.per_state["t_reach"]])
    m = np.array([np.inf if x is None else x for x in ev.per_state["oracle_steps"]])
    assert np.all(t[np.isfinite(m)] >= m[np.isfinite(m)] - 1e-9) or ev.oracle["label"] == "local"
    # cached: the second evaluation does not solve again (same numbers, instantly)
    again = asap_dsl.evaluate(out, episodes=40, oracle="cache")
    assert again.rows == ev.rows


def test_existing_run_is_never_overwritten_without_force(tiny, tmp_path, capsys):
    out = tmp_path / "run"
    assert asapc(capsys, "train", tiny, "--steps", 200, "--out", out, "--quiet", "--no-eval")[0] == 0
    before = (out / "run.json").read_text()
    code, _, err = asapc(capsys, "train", tiny, "--steps", 200, "--out", out, "--quiet", "--no-eval")
    assert code == 1 and "already holds a run" in err and "--force" in err
    one_line_error(err)
    assert (out / "run.json").read_text() == before
    assert asapc(capsys, "train", tiny, "--steps", 200, "--out", out, "--quiet", "--no-eval", "--force")[0] == 0


@pytest.mark.parametrize("argv, words", [
    (["--steps", "-5"], "whole number of steps"),
    (["--steps", "lots"], "number of steps"),
    (["--steps", "1.5"], "whole number of steps"),
    (["--algo", "sacc"], "invalid choice"),
    (["--preset", "fastest"], "invalid choice"),
    (["--seed", "-1"], "seed"),
    (["--envs", "0"], "positive"),
    (["--task", "nope"], "no task named 'nope'"),
    (["--reward", "rhoo"], "unknown reward 'rhoo'"),
    (["--reward", "rho(window = -2)"], "window"),
])
def test_bad_train_flags_get_one_clear_line(tiny, tmp_path, capsys, argv, words):
    code, _, err = asapc(capsys, "train", tiny, "--out", tmp_path / "r", "--quiet", *argv)
    assert code == 2 and words in err and "Traceback" not in err, err
    last = err.strip().splitlines()[-1]  # argparse prints its usage first, then the one line that matters
    assert last.startswith("asapc") and words in last
    assert not (tmp_path / "r" / "run.json").exists()


@pytest.fixture()
def trained(tiny, tmp_path):
    out = tmp_path / "run"
    asap_dsl.train(tiny, steps=200, n_envs=2, out=out, settings=FAST, evaluate=False)
    return out


def test_eval_bad_run_directories_get_one_line(tiny, trained, tmp_path, capsys):
    cases = {}
    cases["missing"] = tmp_path / "nowhere"
    (tmp_path / "empty").mkdir()
    cases["empty"] = tmp_path / "empty"
    half = tmp_path / "half"
    half.mkdir()
    (half / "run.json").write_text('{"format": 1, "config": ')  # cut off mid-write
    cases["half-written manifest"] = half
    for name, path in cases.items():
        code, _, err = asapc(capsys, "eval", path, "--no-oracle")
        assert code == 1, name
        one_line_error(err)
    # a run whose model never got written (killed before its first validation: the manifest has none)
    (trained / "model.zip").unlink()
    manifest = json.loads((trained / "run.json").read_text())
    manifest["model"] = None
    (trained / "run.json").write_text(json.dumps(manifest))
    code, _, err = asapc(capsys, "eval", trained, "--no-oracle")
    assert code == 1 and "no trained model" in err and "--resume`" in err
    one_line_error(err)


def test_eval_refuses_a_changed_or_other_spec(tiny, trained, tmp_path, capsys):
    other = tmp_path / "other.asap"
    other.write_text(TINY.replace("deadline 20", "deadline 19"))
    code, _, err = asapc(capsys, "eval", trained, "--spec", other, "--no-oracle")
    assert code == 1 and "trained on another spec" in err
    one_line_error(err)
    # the run's copy tampered with
    copy = trained / "spec.asap"
    saved = copy.read_text()
    copy.write_text(saved + "\n# edited\n")
    code, _, err = asapc(capsys, "eval", trained, "--no-oracle")
    assert code == 1 and "changed after training" in err
    one_line_error(err)
    copy.write_text(saved)
    # the original file edited since training
    tiny.write_text(TINY.replace("tolerances 20, 10, 5", "tolerances 20, 10"))
    code, _, err = asapc(capsys, "eval", trained, "--no-oracle")
    assert code == 1 and "has changed since" in err
    one_line_error(err)
    # ... and with its own copy it still evaluates
    code, out, _ = asapc(capsys, "eval", trained, "--no-oracle", "--spec", copy, "--episodes", "20")
    assert code == 0 and "within" in out


@pytest.mark.parametrize("argv, words", [
    (["--tolerances", "25"], "outside 1..20"),
    (["--episodes", "0"], "positive"),
    (["--tolerances", "a,b"], "whole numbers"),
    (["--seed", "x"], "whole number"),
])
def test_bad_eval_flags(trained, capsys, argv, words):
    code, _, err = asapc(capsys, "eval", trained, "--no-oracle", *argv)
    assert code == 2 and words in err and "Traceback" not in err


def test_resume_refuses_other_settings_and_changed_spec(tiny, trained, capsys):
    code, _, err = asapc(capsys, "train", tiny, "--out", trained, "--resume", "--algo", "td3", "--quiet")
    assert code == 1 and "--algo td3 (the run has sac)" in err
    one_line_error(err)
    tiny.write_text(TINY + "\n# a comment changes the hash\n")
    code, _, err = asapc(capsys, "train", tiny, "--out", trained, "--resume", "--quiet")
    assert code == 1 and "has changed since this run was trained" in err


def test_sigterm_checkpoints_and_resume_continues_the_step_count(tiny, tmp_path):
    out = tmp_path / "run"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    cmd = [sys.executable, "-m", "asap_dsl.cli", "train", str(tiny), "--steps", "1000000", "--envs", "2",
           "--out", str(out), "--no-eval"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.time() + 120
    while time.time() < deadline and not (out / "run.json").is_file():
        time.sleep(0.2)
    assert (out / "run.json").is_file(), proc.communicate(timeout=60)
    time.sleep(4.0)  # well into training
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "--resume" in err
    assert "training: task go, sac, asap reward, default preset, seed 0" in err  # the log-style progress
    manifest = RunDir(out).read_manifest()
    assert manifest["status"] == "interrupted"
    stopped_at = manifest["steps_done"]
    state = json.loads((out / "checkpoint" / "state.json").read_text())
    assert state["steps"] == stopped_at > 0
    # the header, and the validations done before the stop (none when it came before the first)
    curves_before = (out / "curves.csv").read_text().splitlines() if (out / "curves.csv").is_file() else []
    # resume with a new total: it continues from stopped_at, not from 0
    res = asap_dsl.train(tiny, out=out, resume=True, steps=stopped_at + 400, evaluate=False)
    assert res.status == "finished"
    assert stopped_at + 400 <= res.steps <= stopped_at + 400 + 2
    curves_after = (out / "curves.csv").read_text().splitlines()
    assert curves_after[: len(curves_before)] == curves_before
    new_steps = [int(line.split(",")[0]) for line in curves_after[max(1, len(curves_before)):]]
    assert new_steps and min(new_steps) > stopped_at
    assert RunDir(out).read_manifest()["steps_done"] == res.steps
    assert res.seconds >= float(state["seconds"])


def test_validation_states_are_not_the_evaluation_states(tiny):
    from asap_dsl.backends.rl.config import VALIDATION_SEED, resolve_config
    from asap_dsl.sampling import EVAL_SEED, evaluation_states

    prog = asap_dsl.load(tiny)
    cfg = resolve_config(prog)
    assert cfg.validation_seed == VALIDATION_SEED != EVAL_SEED
    a = evaluation_states(prog.system, 50, seed=cfg.validation_seed)
    b = evaluation_states(prog.system, 50, seed=EVAL_SEED)
    assert not np.allclose(a, b)


def test_settings_precedence_flag_over_block_over_preset(tiny):
    from asap_dsl.backends.rl.config import resolve_config
    from asap_dsl.backends.rl.presets import get_preset

    text = TINY.replace("tolerances 20, 10, 5", "tolerances 20, 10, 5\n  train { algo = td3, steps = 5000, "
                                                "learning_rate = 0.002 }")
    prog = asap_dsl.loads(text, "rail.asap")
    cfg = resolve_config(prog)
    assert (cfg.algo, cfg.steps, cfg.hyper["learning_rate"]) == ("td3", 5000, 0.002)
    cfg = resolve_config(prog, algo="sac", steps=700, settings={"learning_rate": 1e-4})
    assert (cfg.algo, cfg.steps, cfg.hyper["learning_rate"]) == ("sac", 700, 1e-4)
    paper = resolve_config(prog, preset="paper", algo="ddpg")
    assert paper.hyper["learning_rate"] == 0.002  # the block beats the preset
    assert paper.n_envs == 1 and paper.hyper["batch_size"] == get_preset("paper").settings("ddpg")["batch_size"]
    assert paper.hyper["buffer_size"] == 5000 + 1  # never more memory than the run can fill


def test_time_limit_ends_the_run_as_finished(tiny, tmp_path, monkeypatch):
    from asap_dsl.backends.rl import validation

    # Validation may step its states as many steps as training took: in 3 s this run trains about a
    # thousand steps, a validation steps two thousand (the budget's rule is tested on its own).
    monkeypatch.setattr(validation, "BUDGET", 1e9)
    # JAX's first compile (a cold cache) would fill the 3 s, and so would the oracle's demonstrations
    res = asap_dsl.train(tiny, steps=10_000_000, n_envs=2, out=tmp_path / "r", settings=FAST, time_limit=3.0,
                         eval_episodes=30, engine="sb3", demonstrations=0)
    assert res.status == "finished" and 0 < res.steps < 10_000_000
    assert 3.0 <= res.seconds < 10.0
    assert RunDir(tmp_path / "r").read_manifest()["config"]["time_limit"] == 3.0
    assert res.evaluation is not None
    # validated on the clock (every 0.1 s here), though the step budget is far away: by steps there would
    # be none (the first at 10M / 30 steps); a loaded machine fits fewer in, so only a few are asked for
    assert len(res.curves) >= 3
