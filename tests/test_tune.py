"""asapc tune: from a poor train block it finds a better one within its budget and writes it into
the task (the rest of the file byte for byte, the spec still clean); a tuning killed mid-trial
continues without running its finished trials again, the killed trial from its checkpoint; a time
limit stops it and the next call goes on; a trial runs on a local Ray cluster; bad flags are one
sentence. The rail is trained on the sb3 engine (no JAX compile per trial), 2,000 steps a trial."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import asap_dsl
from asap_dsl.runs import RunDir
from conftest import RAIL, asapc, one_line_error

pytest.importorskip("optuna")

POOR = "  train { learning_rate = 1e-6, steps = 2000, n_envs = 4, net_arch = [32, 32] }\n"
SPEC = RAIL.replace("  tolerances 20, 10, 5\n", "  tolerances 20, 10, 5  # three of them\n" + POOR)
FAST = ["--engine", "sb3"]


@pytest.fixture()
def spec(tmp_path):
    p = tmp_path / "rail.asap"
    p.write_text(SPEC)
    return p


def _study(out: Path):
    import optuna

    from asap_dsl.backends.tune.study import STUDY, open_storage

    storage, _ = open_storage(out)
    return optuna.load_study(study_name=STUDY, storage=storage)


def test_a_poor_block_is_beaten_and_written_into_the_task(spec, tmp_path, capsys):
    out = tmp_path / "tune"
    code, stdout, err = asapc(capsys, "tune", spec, "--trials", 3, "--out", out, "--write", *FAST)
    assert code == 0, err
    assert "Traceback" not in err
    assert "starting point, the task's own train block: score" in err
    assert "trial 1 of 3: learning_rate = " in err and "trial 3 of 3: score" in err and "best so far" in err
    assert "3 of 3 trials done (3 in this call" in err
    best = json.loads((out / "best.json").read_text())
    assert best["improved"] and best["score"] > best["baseline"], err
    # every trial a run directory, scored on the validation states, never evaluated
    runs = sorted((out / "trials").iterdir())
    assert len(runs) == 3 and all(not (r / "eval.json").exists() for r in runs)
    assert RunDir(out / "start").read_manifest()["config"]["validation_seed"] == 7
    # the block printed is the one written; everything else is as it was, byte for byte
    new = spec.read_text()
    head, tail = SPEC.split(POOR)
    assert new.startswith(head) and new.endswith(tail) and "learning_rate = 1e-6" not in new
    assert stdout.startswith("train {") and "written into task go of" in stdout
    prog = asap_dsl.load(spec)
    block = prog.task("go").model.train
    assert block["steps"] == 2000 and block["learning_rate"] == best["settings"]["learning_rate"]
    assert [k for k in block if k not in best["settings"]] == ["steps", "n_envs"]
    assert asapc(capsys, "lint", spec)[0] == 0


def test_a_killed_tuning_continues_without_running_finished_trials_again(spec, tmp_path, capsys):
    out = tmp_path / "tune"
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1", ASAP_CHECKPOINT_SECONDS="1")
    cmd = [sys.executable, "-m", "asap_dsl.cli", "tune", str(spec), "--trials", "2", "--out", str(out), *FAST]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    seen, first = [], None
    deadline = time.time() + 150
    try:
        for line in proc.stderr:  # the first trial done, the second one training past a checkpoint
            seen.append(line)
            if line.startswith("trial 1 of 2: score"):
                break
        while time.time() < deadline and first is None:
            for d in (out / "trials").iterdir():
                m = RunDir(d).read_manifest() if (d / "run.json").is_file() else {}
                if m.get("status") == "finished":
                    continue
                ckpt = d / "checkpoint" / "state.json"
                if ckpt.is_file() and json.loads(ckpt.read_text())["steps"] > 0:
                    first = d
            time.sleep(0.1)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=60)
    assert first is not None, "".join(seen)
    done = [d for d in (out / "trials").iterdir() if d != first]
    assert len(done) == 1
    before = {d: (d / "run.json").stat().st_mtime_ns for d in (out / "start", *done)}
    created = RunDir(first).read_manifest()["created"]
    killed_at = json.loads((first / "checkpoint" / "state.json").read_text())["steps"]

    code, stdout, err = asapc(capsys, "tune", spec, "--trials", 2, "--out", out, *FAST)
    assert code == 0, err
    assert "1 trial(s) done" in err and "trial 2 of 2 (continues trial 2 from its checkpoint)" in err
    assert "2 of 2 trials done (1 in this call" in err
    assert {d: (d / "run.json").stat().st_mtime_ns for d in before} == before  # not run again
    m = RunDir(first).read_manifest()
    assert m["created"] == created and m["status"] == "finished"
    assert m["steps_done"] >= 2000 or "plateau_step" in m  # all its steps, or ended on its plateau (conftest.completed)
    assert killed_at > 0
    states = [t.state.name for t in _study(out).trials]
    assert states == ["COMPLETE", "FAIL", "COMPLETE"], states  # the killed one, then its continuation


def test_a_time_limit_stops_and_the_next_call_goes_on(spec, tmp_path, capsys):
    out = tmp_path / "tune"
    # 10,000 steps a trial: more than any machine trains in the 2 s (the block's 2,000 took under 2 s on CI)
    longer = [*FAST, "--steps", 10_000]
    code, stdout, err = asapc(capsys, "tune", spec, "--trials", 1, "--out", out, "--time-limit", 2, *longer)
    assert code == 0, err
    assert "stopped at the time limit: run the same command again to continue" in err
    assert "0 of 1 trials done" in err and "no trial scored higher" in stdout
    m = RunDir(out / "start").read_manifest()
    assert m["steps_done"] < 10_000
    code, stdout, err = asapc(capsys, "tune", spec, "--trials", 1, "--out", out, *longer)
    assert code == 0, err
    assert RunDir(out / "start").read_manifest()["created"] == m["created"]  # continued, not begun again
    assert "1 of 1 trials done" in err


def test_a_trial_runs_on_a_local_ray_cluster(spec, tmp_path, capsys):
    pytest.importorskip("ray.tune")
    out = tmp_path / "tune"
    code, stdout, err = asapc(capsys, "tune", spec, "--trials", 1, "--out", out, "--ray", "local", "--steps", 1000, *FAST)
    assert code == 0, err
    assert "trial 1 of 1: score" in err and "1 of 1 trials done" in err
    assert [t.state.name for t in _study(out).trials] == ["COMPLETE"]
    (run,) = (out / "trials").iterdir()
    assert RunDir(run).read_manifest()["status"] == "finished"
    assert (out / "ray" / "session-1").is_dir()


@pytest.mark.parametrize("argv, words", [
    (["--trials", "0"], "expected a positive number"),
    (["--time-limit", "-3"], "positive number of seconds"),
    (["--steps", "lots"], "number of steps"),
    (["--ray", "no address"], "is not a Ray address"),
    (["--task", ""], "--task needs a task name"),
    (["--task", "og"], "no task named 'og'"),
    (["--algo", "sax"], "invalid choice"),
])
def test_bad_tune_flags_are_one_sentence(spec, tmp_path, capsys, argv, words):
    code, _, err = asapc(capsys, "tune", spec, "--out", tmp_path / "t", *argv)
    assert code == 2 and "Traceback" not in err, err
    last = err.strip().splitlines()[-1]  # argparse prints its usage first, then the one line that matters
    assert last.startswith("asapc") and words in last, err
    assert not (tmp_path / "t" / "study.log").exists()


def test_bad_tune_places_are_one_sentence(spec, tmp_path, capsys):
    code, _, err = asapc(capsys, "tune", tmp_path / "none.asap")
    assert code == 1 and "no such file" in err and "Traceback" not in err
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    code, _, err = asapc(capsys, "tune", spec, "--out", other)
    assert code == 1 and "not a tuning" in one_line_error(err)
    # a tune directory continues only the tuning it began
    from asap_dsl.backends.tune import Tuning

    Tuning.open(str(spec), None, engine="sb3", out=str(tmp_path / "t")).close()
    code, _, err = asapc(capsys, "tune", spec, "--out", tmp_path / "t", "--steps", 5000, *FAST)
    assert code == 1 and "it was begun with steps 2000 (now 5000)" in one_line_error(err)
    spec.write_text(SPEC.replace("deadline 20", "deadline 25"))
    code, _, err = asapc(capsys, "tune", spec, "--out", tmp_path / "t", *FAST)
    assert code == 1 and "the spec has changed" in one_line_error(err)


def test_the_block_is_written_in_place_whatever_the_file_looks_like(tmp_path):
    from asap_dsl.backends.tune.block import BlockError, write_block

    win = {"learning_rate": 0.000316, "net_arch": [64, 64], "gamma": 0.99}
    # CRLF line ends, a byte-order mark and comments: kept; the task's block replaced in place
    raw = SPEC.replace("\n", "\r\n").encode()
    p = tmp_path / "crlf.asap"
    p.write_bytes(b"\xef\xbb\xbf" + raw)
    os.chmod(p, 0o640)
    write_block(p, "go", {"steps": 2000, **win})
    data = p.read_bytes()
    head, tail = SPEC.replace("\n", "\r\n").encode().split(POOR.replace("\n", "\r\n").encode())
    assert data.startswith(b"\xef\xbb\xbf" + head) and data.endswith(tail)
    assert b"\n" not in data.replace(b"\r\n", b"") and (p.stat().st_mode & 0o777) == 0o640
    assert asap_dsl.load(p).task("go").model.train == {"steps": 2000, **win}
    # no block yet: one is added as the task's last clause, indented as its clauses
    p.write_text(RAIL)
    write_block(p, "go", win)
    assert p.read_text() == RAIL.replace("  tolerances 20, 10, 5\n", "  tolerances 20, 10, 5\n  train { learning_rate = "
                                         "0.000316, net_arch = [64, 64], gamma = 0.99 }\n")
    # a setting the language refuses: the file is left as it was
    before = p.read_bytes()
    with pytest.raises(BlockError, match="does not check"):
        write_block(p, "go", {"lerning_rate": 0.1})
    assert p.read_bytes() == before
