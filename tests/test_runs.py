"""Run directories, in one process (issue 19): --force replaces only a run, every damaged file is
one sentence, a failed write keeps the last checkpoint, limits are usage errors, hints can be
pasted, and specs with the same file name stay apart. What needs several processes (locks held
by another process, kill -9, Ctrl-C, a full disk, Ray) is tests/test_run_faults.py."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import zipfile
from pathlib import Path

import pytest

import asap_dsl
from asap_dsl.runs import RunDir, RunError, command_line, shell_quote
from conftest import RAIL, asapc, completed

FAST = {"net_arch": [16, 16], "learning_starts": 64, "batch_size": 32}


def _one_sentence(err: str, *words: str) -> str:
    assert "Traceback" not in err, err
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("asapc: error:"), err
    for w in words:
        assert w in lines[0], (w, lines[0])
    assert "\x1b" not in err
    return lines[0]


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """One small trained and evaluated run (with a checkpoint), copied by each test that damages it."""
    d = tmp_path_factory.mktemp("base")
    spec = d / "rail.asap"
    spec.write_text(RAIL)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("ASAP_CACHE_DIR", str(d / "cache"))
        mp.setenv("ASAP_ENGINE", os.environ.get("ASAP_ENGINE") or "numpy")  # as conftest's: no compile
        asap_dsl.train(spec, steps=200, n_envs=2, out=d / "run", settings=FAST, eval_episodes=20, engine="sb3")
    return spec, d / "run"


@pytest.fixture()
def run(base, tmp_path):
    spec, src = base
    dst = tmp_path / "run"
    shutil.copytree(src, dst)
    return dst


# -------------------------------------------------------------------------------- 1. --force
def test_force_replaces_only_a_run(base, run, tmp_path, capsys):
    spec, _ = base
    precious = tmp_path / "precious"
    (precious / "sub").mkdir(parents=True)
    (precious / "thesis.txt").write_text("x")
    code, _, err = asapc(capsys, "train", spec, "--out", precious, "--force", "--steps", 100, "--quiet")
    assert code == 1
    _one_sentence(err, "not a run", "never replaces it")
    assert (precious / "thesis.txt").read_text() == "x" and (precious / "sub").is_dir()

    afile = tmp_path / "afile"
    afile.write_text("y")
    code, _, err = asapc(capsys, "train", spec, "--out", afile, "--force", "--steps", 100, "--quiet")
    assert code == 1 and afile.read_text() == "y"
    _one_sentence(err, "is a file")

    (run / "notes.txt").write_text("mine")  # a run with the user's file in it is not only a run
    code, _, err = asapc(capsys, "train", spec, "--out", run, "--force", "--steps", 100, "--quiet")
    assert code == 1 and (run / "notes.txt").exists()
    _one_sentence(err, "notes.txt", "never replaces it")
    (run / "notes.txt").unlink()

    code, _, err = asapc(capsys, "train", spec, "--out", run, "--steps", 100, "--quiet")  # no --force
    line = _one_sentence(err, "already holds a run", "--resume`", "--force")
    assert "--force`" not in line  # it says how to go on, not to destroy

    before = RunDir(run).read_manifest()
    code, _, err = asapc(capsys, "train", spec, "--out", run, "--force", "--steps", 100, "--quiet", "--no-eval",
                        "--engine", "sb3")
    assert code == 0, err
    after = RunDir(run).read_manifest()
    assert after["config"]["steps"] == 100 and before["config"]["steps"] == 200
    assert not (run / "eval.json").exists()  # the old run's files went with it
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no stage left beside it


# -------------------------------------------------------------------------------- 8. damage
def _truncate(p: Path) -> None:
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])


def _garble(p: Path) -> None:
    raw = bytearray(p.read_bytes())
    for i in range(100, min(len(raw), 4000), 7):
        raw[i] ^= 0x5A
    p.write_bytes(bytes(raw))


def _manifest(run: Path, **changes) -> None:
    m = json.loads((run / "run.json").read_text())
    for k, v in changes.items():
        if v is KeyError:
            m.pop(k)
        elif k in ("n_envs", "observation_scaling", "algo", "seed"):
            m["config"][k] = v
        else:
            m[k] = v
    (run / "run.json").write_text(json.dumps(m))


DAMAGE = {
    "truncated state.pkl": (lambda r: _truncate(r / "checkpoint" / "state.pkl"), "state.pkl"),
    "truncated replay.pkl": (lambda r: _truncate(r / "checkpoint" / "replay.pkl"), "replay.pkl"),
    "garbled checkpoint model": (lambda r: _garble(r / "checkpoint" / "model.zip"), "model.zip"),
    "deleted replay.pkl": (lambda r: (r / "checkpoint" / "replay.pkl").unlink(), "replay.pkl: damaged checkpoint (it is missing"),
    "deleted state.pkl": (lambda r: (r / "checkpoint" / "state.pkl").unlink(), "state.pkl: damaged checkpoint (it is missing"),
    "deleted checkpoint model": (lambda r: (r / "checkpoint" / "model.zip").unlink(), "model.zip: damaged checkpoint"),
    "n_envs is text": (lambda r: _manifest(r, n_envs="eight"), "n_envs = 'eight'"),
    # found by the hostile review: a scaling or an algorithm the tool has no such thing as
    "observation_scaling unknown": (lambda r: _manifest(r, observation_scaling="banana"),
                                    "observation_scaling = 'banana', not one of init, state, none"),
    "algo unknown": (lambda r: _manifest(r, algo="banana"), "algo = 'banana', not one of sac"),
    "seed negative": (lambda r: _manifest(r, seed=-3), "'seed' must be a whole number from 0"),
    "spec_file is a number": (lambda r: _manifest(r, spec_file=123), "'spec_file' is 123"),
    "a key missing": (lambda r: _manifest(r, task=KeyError), "no 'task'"),
    "manifest cut": (lambda r: _truncate(r / "run.json"), "unreadable manifest"),
}


@pytest.mark.parametrize("case", list(DAMAGE))
def test_a_damaged_run_is_one_sentence(base, run, capsys, case):
    spec, _ = base
    damage, words = DAMAGE[case]
    damage(run)
    code, _, err = asapc(capsys, "train", spec, "--out", run, "--resume", "--steps", 300, "--quiet", "--no-eval")
    assert code == 1, err
    _one_sentence(err, words)


def test_a_model_swapped_in_or_deleted_is_refused(base, run, capsys):
    # A real, loadable model with other bytes: the last checkpoint can be the best model itself
    # (byte for byte when both were saved within the zip format's two-second clock), so it is
    # copied with a comment of its own.
    shutil.copy(run / "checkpoint" / "model.zip", run / "model.zip")
    with zipfile.ZipFile(run / "model.zip", "a") as z:
        z.comment = b"swapped in"
    code, _, err = asapc(capsys, "eval", run, "--no-oracle", "--episodes", 10)
    assert code == 1
    _one_sentence(err, "model.zip: not the model this run wrote", "refused")
    (run / "model.zip").unlink()
    code, _, err = asapc(capsys, "eval", run, "--no-oracle", "--episodes", 10)
    assert code == 1
    _one_sentence(err, "model.zip: not the model this run wrote (it is missing)")


def test_a_manifest_naming_another_algorithm_is_refused(run, capsys):
    """Found by the hostile review: with run.json's algo edited from sac to td3, TD3's loader took
    the SAC model and eval reported it as TD3."""
    _manifest(run, algo="td3")
    code, _, err = asapc(capsys, "eval", run, "--no-oracle", "--episodes", 10)
    assert code == 1
    _one_sentence(err, "model.zip: cannot load the model", "SACPolicy, not the TD3Policy of td3")


def test_an_unwritable_oracle_cache_is_a_warning_not_a_failure(base, run, tmp_path, monkeypatch, capsys):
    """Found by the hostile review: eval computed the oracle's ceiling, could not cache it, and
    stopped with exit 1 before showing anything; `asapc oracle` likewise lost what it computed."""
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    monkeypatch.setenv("ASAP_CACHE_DIR", str(blocker))
    code, out, err = asapc(capsys, "eval", run, "--episodes", 10)
    assert code == 0, err
    assert "oracle's results are not cached" in out and "is a file, not a directory" in out
    assert "ASAP gap" in out  # the comparison with the ceiling just computed is shown
    code, out, err = asapc(capsys, "oracle", base[0], "--episodes", 5)
    assert code == 0, err
    assert "minimum steps" in out
    assert err.count("asapc: warning: cannot write") == 1 and "compute them again" in err


def test_eval_json_is_checked_when_read(run):
    r = RunDir(run)
    assert r.read_eval()["episodes"] == 20
    data = json.loads((run / "eval.json").read_text())
    data["per_state"]["t_reach"] = data["per_state"]["t_reach"][:5]
    (run / "eval.json").write_text(json.dumps(data))
    with pytest.raises(RunError, match="per-state results are missing or cut"):
        r.read_eval()
    (run / "eval.json").write_text("{garbled")
    with pytest.raises(RunError, match="unreadable evaluation"):
        r.read_eval()


def test_a_kill_between_commit_and_rename_is_finished_on_the_next_lock(run):
    """The manifest names a new checkpoint that was not yet renamed in: readers find it, and the
    next exclusive holder installs it."""
    r = RunDir(run)
    os.rename(run / "checkpoint", run / "checkpoint.new")
    assert r.checkpoint().directory.name == "checkpoint.new"
    r.acquire(exclusive=True)
    try:
        assert r.checkpoint().directory.name == "checkpoint" and not (run / "checkpoint.new").exists()
    finally:
        r.release()


# -------------------------------------------------------------------------------- 7. write failures
def test_a_failed_checkpoint_write_keeps_the_last_one(base, tmp_path, monkeypatch):
    """A patched writer: the second checkpoint fails with EIO half way (its state.pkl)."""
    from asap_dsl.backends.rl import session

    spec, _ = base
    calls = {"n": 0}
    real = session._rng_state

    def failing(*a, **k):
        calls["n"] += 1
        if calls["n"] == 2:
            raise OSError(errno.EIO, "Input/output error")
        return real(*a, **k)

    monkeypatch.setattr(session, "_rng_state", failing)
    out = tmp_path / "run"
    with pytest.raises(RunError) as info:
        asap_dsl.train(spec, steps=150, n_envs=2, out=out, settings=FAST, evaluate=False, engine="sb3")
    text = str(info.value)
    assert "cannot write" in text and "state.pkl: input/output error" in text and "the checkpoint at step 0 is intact" in text
    assert "--resume`" in text and "\n" not in text
    m = RunDir(out).read_manifest()
    assert m["status"] == "failed" and "input/output error" in m["error"]
    assert RunDir(out).checkpoint().steps == 0 and not (out / "checkpoint.new").exists()
    monkeypatch.setattr(session, "_rng_state", real)
    res = asap_dsl.train(spec, out=out, resume=True, evaluate=False)
    assert completed(res, 150)


def test_an_unwritable_curves_file_during_resume(base, run, capsys):
    spec, _ = base
    (run / "curves.csv").unlink()
    (run / "curves.csv").mkdir()  # as root, a directory in its place is what refuses the rename
    code, _, err = asapc(capsys, "train", spec, "--out", run, "--resume", "--steps", 260, "--quiet", "--no-eval")
    assert code == 1
    _one_sentence(err, "cannot write", "curves.csv", "is intact", "--resume`")
    assert RunDir(run).checkpoint() is not None and RunDir(run).read_manifest()["status"] == "failed"


# -------------------------------------------------------------------------------- 10. limits
def test_sizes_beyond_the_machine_are_usage_errors(base, run, tmp_path, capsys, monkeypatch):
    spec, _ = base
    out = tmp_path / "huge"
    code, _, err = asapc(capsys, "train", spec, "--envs", 100_000_000, "--out", out, "--quiet")
    assert code == 2 and not out.exists()
    assert "--envs 100,000,000 needs about" in err and "Traceback" not in err
    code, _, err = asapc(capsys, "eval", run, "--workers", 1000)
    assert code == 2 and "--force-workers" in err
    monkeypatch.setattr("asap_dsl.limits.available_memory", lambda: 64 * 1024 * 1024)
    code, _, err = asapc(capsys, "eval", run, "--episodes", 1_000_000, "--no-oracle")
    assert code == 2 and "--episodes 1,000,000 needs about" in err


# -------------------------------------------------------------------------------- 11. paths, hints
def test_hints_are_shell_quoted_with_control_characters_escaped(tmp_path):
    names = ["plain", "with space", "it's", "esc\x1b[31mred", "new\nline", "tab\there", "back\\slash"]
    line = command_line(["asapc", "train", *names])
    assert "\x1b" not in line and "\n" not in line and "\t" not in line
    back = subprocess.run(["bash", "-c", f"printf '%s\\0' {line}"], capture_output=True, check=True).stdout
    assert back.split(b"\0")[:-1] == [a.encode() for a in ["asapc", "train", *names]]
    assert shell_quote("run-1") == "run-1"


def test_paths_are_stored_absolute_and_messages_escaped(base, tmp_path, capsys, monkeypatch):
    spec, _ = base
    work = tmp_path / "work"
    work.mkdir()
    (work / "rail.asap").write_text(RAIL)
    monkeypatch.chdir(work)
    out = tmp_path / "odd\x1bname"
    asap_dsl.train("rail.asap", steps=100, n_envs=2, out=out, settings=FAST, evaluate=False, engine="sb3")
    m = RunDir(out).read_manifest()
    assert m["spec_file"] == str(work / "rail.asap")
    code, _, err = asapc(capsys, "train", "rail.asap", "--out", out, "--steps", 100, "--quiet")
    _one_sentence(err, "already holds a run", r"odd\x1bname")  # escaped, never raw
    monkeypatch.chdir(tmp_path)  # elsewhere, the changed-spec check still finds the file
    (work / "rail.asap").write_text(RAIL + "\n# edited\n")
    code, _, err = asapc(capsys, "eval", out, "--no-oracle", "--episodes", 10)
    assert code == 1
    _one_sentence(err, "has changed since", "--spec")


# -------------------------------------------------------------------------------- 6. names
def test_specs_with_the_same_file_name_get_distinct_columns(tmp_path):
    from asap_dsl.backends.compare.paired import column_labels

    a, b, c = tmp_path / "a" / "di.asap", tmp_path / "b" / "di.asap", tmp_path / "c" / "other.asap"
    labels = column_labels([str(a), str(b), str(c)])
    assert labels == {str(a): "a/di", str(b): "b/di", str(c): "other"}
    deep = [tmp_path / "x" / "s" / "di.asap", tmp_path / "y" / "s" / "di.asap"]
    assert sorted(column_labels([str(p) for p in deep]).values()) == ["x/s/di", "y/s/di"]


def test_a_write_under_a_file_names_the_file_in_the_way(tmp_path):
    """`eval --plot blocker/x.png` where blocker is a file: "file exists" told the user nothing."""
    from asap_dsl.runfiles import RunWriteError, writing

    (tmp_path / "blocker").write_text("")
    target = tmp_path / "blocker" / "sub" / "x.png"
    with pytest.raises(RunWriteError) as info, writing(target):
        target.parent.mkdir(parents=True)
    assert f"{tmp_path / 'blocker'} is a file, not a directory" in str(info.value)


def test_the_default_run_name_has_no_control_characters_or_spaces():
    """Found by the hostile review: a spec named `esc\\x1b[31mred\\nl.asap` made a run directory
    with an escape and a newline in its name, printed raw by `train`."""
    from asap_dsl.runs import default_run_name

    assert default_run_name("odd/esc\x1b[31mred\nl b.asap", "park", "td3", "asap", 1) == "esc_[31mred_l_b-park-td3-asap-s1"
    assert default_run_name("specs/dc_motor.asap", "reach", "sac", "rho(window = 5)", 0).startswith("dc_motor-reach-sac-rho-")
