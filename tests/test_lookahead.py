"""The look-ahead that refines a policy on the spec's simulator (``asapc eval --lookahead``)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import asap_dsl
from asap_dsl.backends.compare.controllers import LookaheadController, hold_ladder, lookahead_problem
from asap_dsl.rollout import Evaluator
from asap_dsl.sampling import task_states
from conftest import ROOT, asapc, one_line_error

FAST = {"net_arch": [16, 16], "learning_starts": 64, "batch_size": 32}


class Sluggish:
    """A proportional controller on the DC motor's angle, with gains too low to be quick: a policy
    that reaches, late, from some states."""

    def reset(self, states: np.ndarray) -> None:
        pass

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        theta, omega = states[:, 0], states[:, 1]
        return np.clip(4.0 * (np.pi / 2 - theta) - 0.2 * omega, -20, 20)[:, None]


@pytest.fixture(scope="module")
def motor():
    prog = asap_dsl.load(ROOT / "specs" / "dc_motor.asap")
    states = task_states(prog.system, prog.task("reach_avoid").model, 48, seed=5)
    return prog, Evaluator(prog, "reach_avoid", states)


def test_the_hold_ladder():
    assert hold_ladder(1) == [1] and hold_ladder(2) == [1, 2] and hold_ladder(4) == [1, 2, 3, 4]
    assert hold_ladder(8) == [1, 2, 3, 5, 8] and hold_ladder(10) == [1, 2, 3, 5, 8, 10]


@pytest.mark.parametrize("hold", [1, 5])
def test_the_lookahead_is_never_later_than_the_controller_it_refines(motor, hold):
    prog, ev = motor
    base = ev.run(Sluggish())
    refined = ev.run(LookaheadController(prog, Sluggish(), "reach_avoid", hold=hold))
    # on deterministic dynamics: the base's own continuation is always a candidate
    assert np.all(refined.t_reach <= base.t_reach)
    assert refined.rate(15) > base.rate(15) + 0.1  # and it makes the slow controller quicker
    assert refined.failures()["avoid"] <= base.failures()["avoid"]


def test_the_lookahead_in_chunks_chooses_as_in_one_batch(motor):
    prog, ev = motor
    whole = ev.run(LookaheadController(prog, Sluggish(), "reach_avoid", hold=3))
    chunked = LookaheadController(prog, Sluggish(), "reach_avoid", hold=3, max_batch=5 * 83)  # 5 states a batch
    assert chunked.K == 2 + 27 * 3 and chunked.chunk == 5
    assert np.array_equal(ev.run(chunked).t_reach, whole.t_reach)


def test_the_rollouts_stop_at_the_reach_they_must_beat(motor):
    prog, ev = motor
    c = LookaheadController(prog, Sluggish(), "reach_avoid", hold=3, max_batch=4 * 83)  # 4 states a group
    c.due = np.array([np.inf, 3, 7, 7, 2, np.inf, 12, 7, 7, 7, 40])
    groups = c._groups(t=2)
    seen = np.concatenate([idx for idx, _ in groups])
    assert sorted(seen) == [0, 1, 2, 3, 5, 6, 7, 8, 9, 10]  # state 4 reached at step 2: decided
    for idx, steps in groups:
        assert len(idx) <= 4 and 1 <= steps <= 28
        due = c.due[idx]
        assert steps == (28 if np.isinf(due).any() else min(28, int(due.max()) - 2))  # the latest reach, or the deadline
    c.due[:] = 5
    assert c._groups(t=5) == []  # every choice has reached: no rollout at all


@pytest.mark.parametrize("step_rows", [0, 10**9])
def test_how_states_are_grouped_does_not_change_a_choice(motor, step_rows):
    prog, ev = motor
    reference = ev.run(LookaheadController(prog, Sluggish(), "reach_avoid", hold=5))
    grouped = LookaheadController(prog, Sluggish(), "reach_avoid", hold=5)
    grouped.STEP_ROWS = step_rows  # 0: every reach its own rollout; huge: one rollout for all
    assert np.array_equal(ev.run(grouped).t_reach, reference.t_reach)


def test_the_lookahead_tells_its_progress_and_eval_shows_it_on_a_terminal(motor):
    import io

    from asap_dsl.cli.eval import _Refining

    prog, ev = motor
    seen = []
    result = ev.run(LookaheadController(prog, Sluggish(), "reach_avoid", hold=3, progress=lambda *a: seen.append(a)))
    assert [s for s, _, _ in seen] == list(range(1, 31)) and all(d == 30 for _, d, _ in seen)
    reached = [r for _, _, r in seen]
    assert reached == sorted(reached) and reached[-1] == int(np.isfinite(result.t_reach).sum())

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    screen = Terminal()
    line = _Refining(screen, 48)
    line(12, 30, 20)
    assert "step 12/30, 20/48 states reached" in screen.getvalue()
    line(30, 30, 40)
    assert screen.getvalue().endswith("\r")  # cleared when the rollout ends
    quiet = io.StringIO()
    _Refining(quiet, 48)(12, 30, 20)
    assert quiet.getvalue() == ""  # nothing in a pipe or a log


def test_a_task_with_history_or_time_is_refused_in_one_sentence():
    prog = asap_dsl.load(ROOT / "examples" / "double_integrator.asap")  # `historically` in asap, observes time
    why = lookahead_problem(prog, "park")
    assert why is not None and "temporal operators" in why and "\n" not in why
    with pytest.raises(ValueError, match="temporal operators"):
        LookaheadController(prog, Sluggish(), "park")
    motor = asap_dsl.load(ROOT / "specs" / "dc_motor.asap")
    assert lookahead_problem(motor, "reach") is None
    with pytest.raises(ValueError, match="1 to 30 steps"):
        LookaheadController(motor, Sluggish(), "reach", hold=31)


def test_eval_lookahead_reports_the_refined_policy_and_keeps_eval_json(tiny, tmp_path, capsys):
    run = tmp_path / "run"
    asap_dsl.train(tiny, steps=64, n_envs=2, out=run, settings=FAST, eval_episodes=10, engine="sb3")
    own = (run / "eval.json").read_bytes()
    code, out, err = asapc(capsys, "eval", run, "--episodes", "10", "--lookahead", "3", "--no-oracle", "--format", "json")
    assert code == 0, err
    data = json.loads(out)
    assert "refined by a look-ahead holding actions up to 3 steps" in data["method"]
    assert any("grid actions held 1, 2, 3 steps" in n for n in data["notes"])
    assert (run / "eval.json").read_bytes() == own  # the policy's own evaluation stays the run's
    plain = json.loads(asapc(capsys, "eval", run, "--episodes", "10", "--no-oracle", "--format", "json")[1])
    for mine, theirs in zip(data["rows"], plain["rows"]):  # never below the policy it refines
        assert mine["tolerance"] == theirs["tolerance"] and mine["rate"] >= theirs["rate"]
    code, out, err = asapc(capsys, "eval", run, "--lookahead", "x")
    assert code == 2 and "expected a whole number" in err and "Traceback" not in err
    code, out, err = asapc(capsys, "eval", run, "--lookahead", "21", "--no-oracle")
    assert code == 2 and "1 to 20 steps (the deadline); got 21" in one_line_error(err)


def test_compare_lookahead_adds_the_refined_row_to_table_1(tiny, tmp_path):
    out = tmp_path / "report"
    base = [sys.executable, "-m", "asap_dsl.cli", "compare", str(tiny), "--out", str(out), "--rewards", "asap",
            "--seeds", "1", "--steps", "400", "--episodes", "40", "--workers", "1", "--engine", "sb3", "--quiet"]
    bad = subprocess.run(base + ["--lookahead", "21"], capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and "--lookahead 21 is beyond the deadline of rail go (20 steps" in one_line_error(bad.stderr)
    assert not (out / "runs").exists()  # refused before anything trained
    r = subprocess.run(base + ["--lookahead", "3"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    md = (out / "report.md").read_text()
    assert "ASAP-Phi (sac) + look-ahead 3" in md and "The look-ahead row is the first row's policies" in md
    rows = {}
    for line in md.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 3 and cells[1] in ("ASAP-Phi (sac)", "ASAP-Phi (sac) + look-ahead 3"):
            rows[(cells[0], cells[1])] = float(cells[2].split()[0].strip("*"))
    for T in ("20", "10", "5"):  # the same states: never below the policy it refines
        assert rows[(T, "ASAP-Phi (sac) + look-ahead 3")] >= rows[(T, "ASAP-Phi (sac)")], T
    # kept in the run beside its eval.json, tied to its model
    kept = [p for p in (out / "runs").glob("*/lookahead3-n40.json")]
    assert len(kept) == 1 and json.loads(kept[0].read_text())["model_sha256"] == json.loads(
        (kept[0].parent / "run.json").read_text())["model"]["sha256"]


def test_eval_lookahead_on_a_task_with_history_is_one_sentence(tmp_path, capsys):
    run = tmp_path / "park"
    asap_dsl.train(ROOT / "examples" / "double_integrator.asap", steps=64, n_envs=2, out=run, settings=FAST,
                   evaluate=False, engine="sb3")
    code, out, err = asapc(capsys, "eval", run, "--episodes", "4", "--lookahead", "2", "--no-oracle")
    assert code == 2 and "the look-ahead needs `asap` and `avoid` without temporal operators" in one_line_error(err)


def test_compare_lookahead_on_a_task_with_history_says_why_it_has_no_row(tmp_path):
    out = tmp_path / "report"
    cmd = [sys.executable, "-m", "asap_dsl.cli", "compare", str(ROOT / "examples" / "double_integrator.asap"),
           "--out", str(out), "--rewards", "asap", "--seeds", "1", "--steps", "300", "--episodes", "10",
           "--workers", "1", "--engine", "sb3", "--quiet", "--lookahead", "2"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    md = (out / "report.md").read_text()
    assert "+ look-ahead 2" not in md and "The look-ahead row" not in md
    assert "no look-ahead row (task park: the look-ahead needs `asap` and `avoid` without temporal operators" in md
