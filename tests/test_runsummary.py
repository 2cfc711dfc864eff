"""Run summaries (``asapc compare --summaries DIR``): a sweep whose runs directory is lost goes on
from the summaries it kept, reading its finished runs back instead of training them again."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from asap_dsl.runs import RunDir, RunError
from asap_dsl.runsummary import SUMMARY_FILES, is_summary, restore_summaries, save_summary

# 1000 evaluation states: the runs' own, so that a summary's evaluation is the sweep's
FLAGS = ["--rewards", "asap,rho", "--seeds", "1", "--steps", "400", "--episodes", "1000", "--workers", "2", "--quiet"]


def _sweep(spec, out, summaries, *extra):
    cmd = [sys.executable, "-m", "asap_dsl.cli", "compare", str(spec), "--out", str(out), "--summaries",
           str(summaries), *FLAGS, *extra]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=dict(os.environ))


def _table1(report: Path) -> str:
    return (report / "report.md").read_text().split("## Table 1 — rewards", 1)[1].split("\n## ", 1)[0]


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    """One tiny sweep with its summaries kept (both tests read it; neither trains again)."""
    from conftest import RAIL

    root = tmp_path_factory.mktemp("summaries")
    spec = root / "rail.asap"
    spec.write_text(RAIL)
    first = _sweep(spec, root / "a", root / "kept")
    assert first.returncode == 0, first.stderr
    return spec, root


def test_a_lost_runs_directory_is_read_back_from_its_summaries_not_trained_again(swept):
    tiny, tmp_path = swept
    summaries = tmp_path / "kept"
    kept = sorted(p.name for p in summaries.iterdir())
    assert len(kept) == 2 and kept == sorted(p.name for p in (tmp_path / "a" / "runs").iterdir() if p.is_dir())
    example = next(k for k in kept if "-asap-s0-" in k)
    for name in kept:  # the four small files; the policy's example actions only of the report's example run
        files = {p.name for p in (summaries / name).iterdir()}
        assert files == set(SUMMARY_FILES) | ({"examples.json"} if name == example else set()), (name, files)

    # another machine: a new --out, only the summaries come along
    second = _sweep(tiny, tmp_path / "b", summaries)
    assert second.returncode == 0, second.stderr
    jobs = json.loads((tmp_path / "b" / "sweep.json").read_text())["jobs"]
    assert len(jobs) == 2 and not any(j["trained_now"] for j in jobs)
    assert not any(j["model"] for j in jobs)
    assert _table1(tmp_path / "b") == _table1(tmp_path / "a")  # the same evaluations, the same table
    # the example trajectories drawn again from the recorded actions: the policy's own paths
    for name in ("state_space", "trajectories"):
        assert (tmp_path / "b" / "plots" / f"{name}.png").read_bytes()[:4] == b"\x89PNG", name
    import numpy as np

    import asap_dsl
    from asap_dsl.backends.compare.controllers import OracleController
    from asap_dsl.backends.rl.evaluation import load_run
    from asap_dsl.rollout import Evaluator
    from asap_dsl.runsummary import read_examples

    run = RunDir(tmp_path / "b" / "runs" / example)
    states, actions = read_examples(run, run.read_manifest())
    prog = asap_dsl.load(tiny)
    ev = Evaluator(prog, "go", states)
    replayed = ev.run(OracleController(states, actions, 1), record=True)
    policy = ev.run(load_run(tmp_path / "a" / "runs" / example).controller(), record=True)
    assert np.allclose(replayed.trajectories, policy.trajectories, atol=1e-6, equal_nan=True)
    assert np.array_equal(replayed.t_reach, policy.t_reach)
    runs = (tmp_path / "b" / "report.md").read_text().split("## What was run")[1]
    assert runs.count("| reused |") == 2


def test_the_lookahead_row_is_kept_with_the_summaries_and_named_where_it_cannot_be(swept, tmp_path):
    """A run refined by the look-ahead keeps that evaluation in its summary, so a report made from
    the summaries on another machine has the same row; read back from a summary that lacks it, a
    run is named in the notes instead of leaving the row with fewer seeds silently."""
    spec, root = swept
    shutil.copytree(root / "kept", tmp_path / "kept")
    r = _sweep(spec, tmp_path / "c", tmp_path / "kept", "--lookahead", "2")
    assert r.returncode == 0, r.stderr
    md = (tmp_path / "c" / "report.md").read_text()
    assert "+ look-ahead 2" not in _table1(tmp_path / "c")
    assert "rail go sac asap seed 0: not in the look-ahead row (its summary kept no model" in md
    assert "rail go sac rho seed 0: not in the look-ahead row" not in md  # only the refined reward's runs

    # where the models are, the refinement goes into the runs and their summaries
    shutil.copytree(root / "a", tmp_path / "a", ignore=shutil.ignore_patterns(".lock"))
    r = _sweep(spec, tmp_path / "a", tmp_path / "kept", "--lookahead", "2")
    assert r.returncode == 0, r.stderr
    refined = _table1(tmp_path / "a")
    assert "ASAP-Phi (sac) + look-ahead 2" in refined
    assert [p.parent.name for p in (tmp_path / "kept").glob("*/lookahead2-n1000.json")] == \
        [p.name for p in (tmp_path / "kept").iterdir() if "-asap-" in p.name]
    # another machine, the summaries only: the same table, the row included
    r = _sweep(spec, tmp_path / "d", tmp_path / "kept", "--lookahead", "2")
    assert r.returncode == 0, r.stderr
    assert _table1(tmp_path / "d") == refined
    assert "not in the look-ahead row" not in (tmp_path / "d" / "report.md").read_text()


def test_a_summary_is_refused_for_an_unfinished_run_and_never_overwrites_a_run(swept, tmp_path):
    _, root = swept
    shutil.copytree(root / "a", tmp_path / "a", ignore=shutil.ignore_patterns(".lock"))
    shutil.copytree(root / "kept", tmp_path / "kept")
    run = next(p for p in (tmp_path / "a" / "runs").iterdir() if p.is_dir())
    manifest = json.loads((run / "run.json").read_text())
    # a summary without its model: reportable, its evaluation checked against the model's record
    bare = tmp_path / "bare"
    save_summary(run, bare)
    copy = RunDir(bare / run.name)
    assert is_summary(copy, copy.read_manifest()) and copy.read_eval()["model_sha256"] == manifest["model"]["sha256"]
    with pytest.raises(RunError, match="not the model this run wrote"):
        copy.model_file()
    # a changed evaluation is refused when read back
    ev = json.loads(copy.eval_path.read_text())
    ev["model_sha256"] = "0" * 64
    copy.eval_path.write_text(json.dumps(ev))
    with pytest.raises(RunError):
        copy.read_eval()
    # a run that is not finished has no summary
    (run / "run.json").write_text(json.dumps({**manifest, "status": "interrupted"}))
    with pytest.raises(RunError, match="not finished"):
        save_summary(run, tmp_path / "other")
    assert not (tmp_path / "other" / run.name).exists()
    # restoring never touches a run that is there
    (run / "run.json").write_text(json.dumps(manifest))
    before = (run / "run.json").read_text()
    assert restore_summaries(tmp_path / "kept", tmp_path / "a" / "runs") == []
    assert (run / "run.json").read_text() == before and (run / "model.zip").is_file()
    assert restore_summaries(tmp_path / "missing", tmp_path / "a" / "runs") == []
    shutil.rmtree(tmp_path / "a" / "runs")
    assert len(restore_summaries(tmp_path / "kept", tmp_path / "a" / "runs")) == 2
