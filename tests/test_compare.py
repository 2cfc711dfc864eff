"""``asapc compare``: a tiny sweep end to end, its report (Markdown and self-contained HTML, checked
in headless Chromium), resumption after SIGTERM, the greedy and oracle controllers, and Ray."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import asap_dsl
from asap_dsl import cli
from conftest import RAIL

TINY = RAIL

FLAGS = ["--rewards", "asap,rho", "--seeds", "1", "--steps", "400", "--episodes", "60", "--workers", "2"]


def _sweep(spec, out, *extra, timeout=600):
    cmd = [sys.executable, "-m", "asap_dsl.cli", "compare", str(spec), "--out", str(out), *FLAGS, *extra]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=dict(os.environ))


def _manifests(out: Path) -> dict:
    return {p.parent.name: json.loads(p.read_text()) for p in sorted((out / "runs").glob("*/run.json"))}


def test_greedy_and_oracle_controllers(tiny):
    from asap_dsl.backends.compare.controllers import GreedyController, OracleController, candidate_actions
    from asap_dsl.backends.oracle.solver import run as oracle_run
    from asap_dsl.rollout import rollout

    prog = asap_dsl.load(tiny)
    grid = candidate_actions(np.array([-1.0, -2.0]), np.array([1.0, 2.0]), budget=25)
    assert grid.shape == (25, 2) and {tuple(c) for c in grid} >= {(-1, -2), (1, 2), (-1, 2), (1, -2)}
    states = np.array([[-1.0], [0.0], [1.5], [1.0]])
    g = rollout(prog, "go", GreedyController(prog, "go"), states)
    # full speed towards the goal is both greedy and time-optimal on a rail
    assert g.t_reach.tolist() == [9.0, 4.0, 2.0, 0.0]
    rep = oracle_run(prog, "go", states=states)
    o = rollout(prog, "go", OracleController([r.x0 for r in rep.results], [r.actions for r in rep.results], 1), states)
    assert np.array_equal(o.t_reach, rep.steps)  # the replay reproduces the oracle's minima exactly


def test_compare_writes_the_report_and_reuses_finished_runs(tiny, tmp_path):
    out = tmp_path / "report"
    r = _sweep(tiny, out, "--engine", "sb3")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    assert "Table 1 — rewards" in r.stdout and "oracle ceiling" in r.stdout
    md = (out / "report.md").read_text()
    for needle in ("## Table 1 — rewards", "ASAP-Phi (sac)", "ρ reward (sac)", "greedy look-ahead", "oracle ceiling",
                   "## ASAP gap", "## What was run", "plots/success_vs_tolerance.png", "oracle ("):
        assert needle in md, needle
    for name in ("state_space", "success_vs_tolerance", "steps_vs_oracle", "trajectories", "training_curves"):
        assert (out / "plots" / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
    html = (out / "report.html").read_text()
    assert "http://" not in html and "https://" not in html and "<link" not in html and "<script" not in html
    first = _manifests(out)
    assert len(first) == 2 and all(m["status"] == "finished" for m in first.values())
    assert {m["config"]["engine"] for m in first.values()} == {"sb3"}  # --engine reaches every run
    # again: nothing is retrained, the report is the same
    r2 = _sweep(tiny, out, "--engine", "sb3")
    assert r2.returncode == 0, r2.stderr
    assert _manifests(out) == first
    assert "reused" in (out / "report.md").read_text()


def test_compare_resumes_after_sigterm(tiny, tmp_path):
    out = tmp_path / "report"
    cmd = [sys.executable, "-m", "asap_dsl.cli", "compare", str(tiny), "--out", str(out), "--rewards",
           "asap,rho,distance", "--seeds", "1", "--steps", "3000", "--episodes", "40", "--workers", "1", "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 240
    while time.time() < deadline:  # wait for the first run to finish and the second to be training
        m = _manifests(out)
        if any(v["status"] == "finished" for v in m.values()) and len(m) >= 2:
            break
        time.sleep(0.2)
    time.sleep(0.5)  # into the second run (a run of 3000 steps takes a few seconds)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "same command" in err
    before = _manifests(out)
    assert sorted(m["status"] for m in before.values()) == ["finished", "interrupted"], before
    finished = next(k for k, m in before.items() if m["status"] == "finished")
    interrupted = next(k for k, m in before.items() if m["status"] == "interrupted")
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    after = _manifests(out)
    assert len(after) == 3 and all(m["status"] == "finished" for m in after.values())
    assert after[finished] == before[finished]                        # not retrained
    assert after[interrupted]["created"] == before[interrupted]["created"]  # resumed, not started over
    resumed = after[interrupted]  # all its steps, or ended on its plateau (conftest.completed)
    assert resumed["steps_done"] > before[interrupted]["steps_done"]
    assert resumed["steps_done"] >= 3000 or "plateau_step" in resumed
    assert (out / "report.html").is_file() and "ρ reward" in (out / "report.md").read_text()
    status = {r["run_dir"].rsplit("/", 1)[1]: r for r in json.loads((out / "sweep.json").read_text())["jobs"]}
    assert not status[finished]["trained_now"] and status[interrupted]["resumed"]
    runs = (out / "report.md").read_text().split("## What was run")[1]
    assert runs.count("| reused |") == 1 and runs.count("| resumed |") == 1 and runs.count("| trained now |") == 1


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def test_html_report_renders_in_headless_chromium_without_requests(tiny, tmp_path):
    exe = _chromium()
    if exe is None:
        if os.environ.get("CI"):
            pytest.fail("CI must install Debian's chromium (see .ci/run)")
        pytest.skip("chromium is not installed (apt-get install chromium)")
    playwright = pytest.importorskip("playwright.sync_api")
    out = tmp_path / "report"
    r = _sweep(tiny, out)
    assert r.returncode == 0, r.stderr
    page_file = (out / "report.html").resolve()
    requests = []
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, args=["--no-sandbox", "--disable-gpu",
                                                                "--disable-background-networking"])
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.on("request", lambda req: requests.append(req.url))
        page.goto(page_file.as_uri())
        page.wait_for_load_state("load")
        tables = page.eval_on_selector_all("table", "els => els.map(e => e.id)")
        images = page.eval_on_selector_all("img", "els => els.map(e => [e.id, e.complete, e.naturalWidth])")
        shot = tmp_path / "report.png"
        page.screenshot(path=str(shot), full_page=True)
        browser.close()
    assert tables == ["table1", "gap", "runs"]
    assert {i[0] for i in images} == {"plot-state_space", "plot-success_vs_tolerance", "plot-steps_vs_oracle",
                                      "plot-trajectories", "plot-training_curves"}
    assert all(complete and width >= 900 for _, complete, width in images), images  # loaded, and readable
    assert [u for u in requests if not u.startswith("data:")] == [page_file.as_uri()]
    assert shot.stat().st_size > 20_000


def test_ray_sweep_matches_the_local_one(tiny, tmp_path):
    ray = pytest.importorskip("ray")
    from asap_dsl.backends.compare.paired import compare

    kw = dict(rewards=("asap", "rho"), algos=("sac",), seeds=1, steps=300, episodes=40)
    local = compare([str(tiny)], out=str(tmp_path / "local"), workers=1, **kw)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        remote = compare([str(tiny)], out=str(tmp_path / "ray"), ray="auto", **kw)
    finally:
        ray.shutdown()
    assert [r["status"] for r in remote.results] == ["finished", "finished"]
    assert [Path(r["run_dir"]).name for r in remote.results] == [Path(r["run_dir"]).name for r in local.results]
    for a, b in zip(local.results, remote.results):  # one torch thread, fixed seed: the same runs
        ea = json.loads((Path(a["run_dir"]) / "eval.json").read_text())
        eb = json.loads((Path(b["run_dir"]) / "eval.json").read_text())
        # The oracle's columns come with its cached ceiling, which the sweep computes beside the
        # training: a run evaluated before it is cached has none. The policies' own must agree.
        def own(ev):
            return ({k: v for k, v in ev["per_state"].items() if not k.startswith("oracle")},
                    [{k: v for k, v in r.items() if k != "ceiling"} for r in ev["rows"]])

        assert own(ea) == own(eb)

    def tables(md: str) -> str:  # everything but the wall times of "What was run"
        return md.split("## What was run")[0]

    assert tables(local.markdown.read_text()) == tables(remote.markdown.read_text())


def test_bad_compare_flags(tiny, capsys):
    def run(*argv):
        try:
            code = cli.main([str(a) for a in argv])
        except SystemExit as e:
            code = e.code
        return code, capsys.readouterr().err

    code, err = run("compare", tiny, "--algos", "sacc")
    assert code == 2 and "unknown algorithm 'sacc'" in err
    code, err = run("compare", tiny, "--workers", "1000")
    assert code == 2 and "--force-workers" in err
    code, err = run("compare", tiny, "--rewards", "asap,bogus")
    assert code == 2 and "unknown reward 'bogus'" in err
    code, err = run("compare", tiny, "--tasks", "nope")
    assert code == 2 and "no task named 'nope'" in err
    code, err = run("compare", tiny, "--algos", "sac,a2c", "--engine", "sbx")  # checked before anything trains
    assert code == 2 and "the sbx engine has no a2c" in err
    code, err = run("compare", tiny, "--algos", "sac,td3", "--imitation", "0.5")
    assert code == 2 and "only SAC on the sbx engine imitates; this run trains TD3" in err
    code, err = run("compare", tiny, "--algos", "sac,ppo", "--search-iterations", "5")
    assert code == 2 and "this run trains PPO" in err
    assert "Traceback" not in err


def test_a_sweep_passes_the_learner_phases_to_every_run(tiny):
    """``--imitation`` and ``--search-iterations`` reach every run's configuration (0 turning the
    default's phases off: the learner alone, as the paper compares it), and its run directory."""
    from asap_dsl.backends.compare.sweep import job_config, job_dir, plan

    prog = asap_dsl.load(tiny)
    default = plan([tiny], None, ["asap", "rho"], ["sac", "td3", "ppo"], 1)
    alone = plan([tiny], None, ["asap", "rho"], ["sac", "td3", "ppo"], 1, imitation=0, search_iterations=0)
    assert len(default) == len(alone) == 4
    for d, a in zip(default, alone):
        cd, ca = job_config(d, prog), job_config(a, prog)
        assert ca.imitation == 0.0 and ca.policy_search is None and "activation_fn" not in ca.hyper
        assert (cd.imitation > 0) == (d.algo == "sac") and (cd.policy_search is not None) == (d.algo != "ppo")
        assert (job_dir(Path("r"), d, prog, cd) == job_dir(Path("r"), a, prog, ca)) == (d.algo == "ppo")
    assert alone[0].training() == "default (imitation 0, search iterations 0)" and default[0].training() == "default"


def test_sweep_workers_each_hold_their_own_core(monkeypatch):
    """Two workers on two cores: one each (their helper threads stay off the other's); more workers
    than cores, or one: the kernel places them."""
    from types import SimpleNamespace

    from asap_dsl.backends.compare import sweep

    monkeypatch.setattr(sweep.os, "sched_getaffinity", lambda pid: {3, 5})
    alive = lambda core: SimpleNamespace(core=core, process=SimpleNamespace(is_alive=lambda: True))  # noqa: E731
    dead = SimpleNamespace(core=3, process=SimpleNamespace(is_alive=lambda: False))
    assert sweep._free_core([], 2) == 3
    assert sweep._free_core([alive(3)], 2) == 5
    assert sweep._free_core([dead, alive(5)], 2) == 3  # a dead worker's core is free again
    assert sweep._free_core([], 1) is None and sweep._free_core([], 3) is None


def test_what_was_run_says_what_each_run_did_beyond_its_learner():
    from asap_dsl.backends.compare.paired import run_phases

    alone = {"config": {"imitation": 0.0}}
    assert run_phases(alone) == "the learner alone"
    package = {"config": {"imitation": 0.1},
               "demonstrations": {"added": 2268, "searcher": "oracle"},
               "late_demonstrations": [{"added": 0}, {"added": 228, "searcher": "oracle"}],
               "policy_search": {"iterations": 1000, "kept_iteration": 775}}
    assert run_phases(package) == ("oracle's paths of 2,268 states from the start, imitated (weight 0.1); "
                                   "oracle's paths of 228 states on a stall; search: iteration 775 of 1,000 kept")
    none_kept = {"config": {}, "demonstrations": {"added": 28, "searcher": "planner"},
                 "policy_search": {"iterations": 40, "kept_iteration": None}}
    assert run_phases(none_kept) == ("planner's paths of 28 states from the start; "
                                     "search: 40 iterations, the learner's model kept")
    gained = {"config": {}, "policy_search": {"iterations": 1000, "kept_iteration": 75, "action_gain": 1.1}}
    assert run_phases(gained) == "search: iteration 75 of 1,000 kept, actions with gain 1.1"


def test_a_summary_evaluated_on_more_states_serves_a_report_on_their_first():
    """A summary keeps no model: the swimmer's runs are evaluated on 1000 states and its report on
    the planner's 200, the first of them. Cut, the evaluation is the one on those states."""
    import asap_dsl
    from asap_dsl.backends.compare.paired import _evaluation, _prefix_evaluation
    from asap_dsl.sampling import EVAL_SEED, task_states

    class Push:  # a proportional pull towards the goal's angle: reaches some states in time, not others
        def reset(self, states):
            pass

        def act(self, obs, states, t):
            return np.clip(20.0 * (np.pi / 2 - states[:, :1]) - 2.0 * states[:, 1:2], -20.0, 20.0)

    prog = asap_dsl.load(Path(__file__).resolve().parents[1] / "specs" / "dc_motor.asap")
    tm = prog.task("reach").model
    many, few = (task_states(prog.system, tm, n, seed=EVAL_SEED) for n in (60, 20))
    whole = _evaluation(prog, "reach", many, None, "push", Push())
    alone = _evaluation(prog, "reach", few, None, "push", Push())
    cut = _prefix_evaluation(whole, prog, "reach", few, None)
    assert cut["episodes"] == 20 and cut["rows"] == alone["rows"] and cut["per_state"] == alone["per_state"]
    assert 0 < alone["rows"][0]["count"] < 20  # a cut that matters
    assert _prefix_evaluation(whole, prog, "reach", task_states(prog.system, tm, 20, seed=7), None) is None
    assert _prefix_evaluation(alone, prog, "reach", many, None) is None  # fewer states cannot serve more
