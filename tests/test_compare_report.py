"""The comparison report's tables and figures from plain data (no training): Table 2 at a
tolerance the spec does not name, the ceiling row named after its bound, the robustness curves
ending at the reach point, and the training curves of many runs."""

from __future__ import annotations

import numpy as np
import pytest

import asap_dsl
from conftest import asapc


def _ev(t_reach: list, tolerances=(30, 25, 15)) -> dict:
    """An evaluation as a run's eval.json holds it: rows at the spec's tolerances, steps per state."""
    from asap_dsl.stats import rate

    rows = [{"tolerance": T, **rate(np.array([t is not None and t <= T for t in t_reach]))} for T in tolerances]
    return {"rows": rows, "per_state": {"t_reach": t_reach}}


def _column(name: str, bound: str, steps: list):
    from asap_dsl.backends.compare.report import Column
    from asap_dsl.stats import rate

    col = Column(f"/x/{name}.asap", "reach", [30, 25, 15], 30, label=name)
    o = np.array([np.inf if s is None else s for s in steps], float)
    col.ceiling = {T: {"tolerance": T, **rate(o <= T)} for T in (30, 25, 20, 15)}
    col.bound = bound
    return col


STEPS = [5, 12, 18, 22, 28, None, 19, 21, 14, 30]  # within 20: 5, 12, 18, 19, 14 -> 50%


def test_table2_shows_a_tolerance_the_spec_does_not_name_counted_from_each_states_steps():
    from asap_dsl.backends.compare.report import Method, ReportData, markdown, table_rows

    col = _column("bicycle", "oracle (local)", [4, 10, 15, 18, 20, 25, 12, 19, 13, 29])
    m = Method("asap/sac", "ASAP-Phi (sac)", "rl", {col.name: [_ev(STEPS), _ev(STEPS[::-1])]})
    rows = {(r[0], r[1]): r[2] for r in table_rows([m], [col], md=True, extra=[20])}
    assert [r[0] for r in table_rows([m], [col], md=True, extra=[20])][::2] == ["30", "25", "20", "15"]
    assert rows[("20", "ASAP-Phi (sac)")] == "50.0 ± 0.0 [" + rows[("20", "ASAP-Phi (sac)")].split("[")[1]
    assert rows[("20", "oracle ceiling")].startswith("80.0 [")  # 4, 10, 15, 18, 20, 12, 19, 13
    assert ("20", "ASAP-Phi (sac)") not in {(r[0], r[1]) for r in table_rows([m], [col], md=True)}
    data = ReportData("t", [col], table1=[m], table2=[m], runs=[], table2_tolerances=[20])
    md = markdown(data)
    t1, t2 = md.split("## Table 2")[0], md.split("## Table 2")[1].split("## ASAP gap")[0]
    assert "| 20 |" not in t1 and "| 20 | ASAP-Phi (sac) | 50.0" in t2
    assert "Within 20 steps (`--table2-tolerances`, beside the spec's own tolerances)" in t2
    # a tolerance every spec names needs no sentence
    assert "Within 30 steps" not in markdown(ReportData("t", [col], [m], [m], [], table2_tolerances=[30]))


def test_a_tolerance_beyond_one_columns_deadline_is_left_blank_there():
    from asap_dsl.backends.compare.report import Column, Method, table_rows

    short = Column("/x/short.asap", "reach", [10, 5], 10, label="short")
    long = _column("long", "oracle (local)", STEPS)
    m = Method("asap/sac", "ASAP-Phi (sac)", "rl", {short.name: [_ev([1, 4, 9, None], (10, 5))], long.name: [_ev(STEPS)]})
    rows = {(r[0], r[1]): r[2:] for r in table_rows([m], [short, long], md=True, extra=[20])}
    assert rows[("20", "ASAP-Phi (sac)")][0] == "—" and rows[("20", "ASAP-Phi (sac)")][1].startswith("50.0")


def test_the_ceiling_row_is_named_after_its_bound():
    from asap_dsl.backends.compare.report import Method, ReportData, ceiling_label, html_page, markdown, table_rows

    oracle, planner = _column("dc", "oracle (exact)", STEPS), _column("swimmer", "planner (achievable)", STEPS)
    assert ceiling_label([oracle]) == "oracle ceiling"
    assert ceiling_label([planner]) == "planner (achievable)"
    assert ceiling_label([oracle, planner]) == "ceiling"
    from asap_dsl.backends.compare.report import Column

    uncached = Column("/x/swimmer.asap", "reach", [50, 40, 30], 50, label="swimmer", black_box=True)
    assert ceiling_label([uncached]) == "planner (achievable)"  # named all the same, its cells blank
    assert {r[2] for r in table_rows([], [uncached], md=True)} == {"—"}
    assert "none, the planner's achievable steps are not cached" in markdown(ReportData("t", [uncached], [], [], []))
    m = Method("asap/sac", "ASAP-Phi (sac)", "rl", {planner.name: [_ev(STEPS)], oracle.name: [_ev(STEPS)]})
    alone = [r for r in table_rows([m], [planner], md=True) if r[1] != m.label]
    assert {r[1] for r in alone} == {"planner (achievable)"} and not any("achievable" in r[2] for r in alone)
    mixed = [r for r in table_rows([m], [oracle, planner], md=True) if r[1] == "ceiling"]
    assert all("achievable" not in r[2] and r[3].endswith(" planner (achievable)") for r in mixed)
    data = ReportData("t", [planner], table1=[m], table2=[m], runs=[], plots={"state_space": b"", "steps_vs_oracle": b""})
    md = markdown(data)
    assert "a lower bound on the true ceiling" in md
    # a black box's sequences are the planner's, everywhere the report names them
    assert "/ (planner's achievable steps); 1.000 is the planner's pace" in md and "oracle's minimum" not in md
    assert "beside the planner (dashed)" in md and "against the planner's" in md
    known = markdown(ReportData("t", [oracle], [m], [m], [], plots={"state_space": b""}))
    assert "/ (oracle's minimum); 1.000 is the physical limit" in known and "beside the oracle (dashed)" in known
    page = html_page(data)
    assert page.count('<tr class="ceiling"><td>') == 2 * 3  # Table 1 and Table 2, a row per tolerance
    assert "planner (achievable)</td>" in page


def test_table2_tolerances_beyond_the_deadline_are_refused_before_anything_trains(tiny, capsys, tmp_path):
    out = tmp_path / "out"
    code, _, err = asapc(capsys, "compare", tiny, "--table2-tolerances", "25", "--out", out)
    assert code == 2 and "tolerance 25 is beyond the deadline of rail go (20 steps" in err, err
    code, _, err = asapc(capsys, "compare", tiny, "--table2-tolerances", "0", "--out", out)
    assert code == 2 and "at least 1 step" in err
    assert "Traceback" not in err and not out.exists()
    from asap_dsl.backends.compare.paired import compare

    with pytest.raises(ValueError, match="beyond the deadline"):
        compare([str(tiny)], out=str(out), table2_tolerances=[21])
    assert not out.exists()


def test_the_robustness_curves_end_at_the_reach_point(tiny):
    from asap_dsl.backends.compare.controllers import GreedyController
    from asap_dsl.backends.compare.paired import robustness_until_reach
    from asap_dsl.rollout import Evaluator

    class Away:  # full speed into the pit: never reaches, ends at the avoid hit
        def reset(self, states):
            pass

        def act(self, obs, states, t):
            return -np.ones((len(states), 1))

    prog = asap_dsl.load(tiny)
    asap = prog.task("go").asap
    states = np.array([[-1.0], [0.0], [1.5], [1.0]])
    res = Evaluator(prog, "go", states).run(GreedyController(prog, "go"), record=True)
    curves = robustness_until_reach(asap, res)
    assert [len(c) for c in curves] == [10, 5, 3, 1]  # t_reach 9, 4, 2, 0: the reach step is the last
    assert all(c[-1] >= 0 for c in curves) and all(x < 0 for c in curves for x in c[:-1])
    away = Evaluator(prog, "go", states[:2]).run(Away(), record=True)  # both left of the goal
    assert not np.isfinite(away.t_reach).any()
    assert [len(c) for c in robustness_until_reach(asap, away)] == [int(e) + 1 for e in away.end_step]


def test_training_curves_of_many_runs_colour_each_method_once():
    from asap_dsl.backends.compare import plots
    from asap_dsl.backends.compare.report import Column

    col = Column("/x/a.asap", "reach", [30, 15], 30, label="a")
    rows = [{"steps": s, "seconds": s / 100, "success_30": s / 3000, "success_15": s / 6000, "return": s / 10}
            for s in (100, 1000, 3000)]
    runs = [(f"method {k}", rows) for k in range(12) for _ in range(2)]  # 12 methods, 2 seeds each
    png = plots.training_curves([col], {col.name: runs})
    assert png[:4] == b"\x89PNG"


def test_planning_a_ceiling_on_two_workers_prints_no_traceback(tiny, tmp_path):
    """A black box's ceiling is `asapc oracle`'s planner, run before compare: the pool's terminate
    at the end of each map must end its workers quietly (they inherited asapc's SIGTERM handler,
    and each printed a KeyboardInterrupt traceback)."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, ASAP_CACHE_DIR=str(tmp_path / "cache"))
    r = subprocess.run([sys.executable, "-m", "asap_dsl.cli", "oracle", str(tiny), "--planner", "--episodes", "6",
                        "--workers", "2", "--samples", "16", "--iterations", "4"],
                       capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stderr
    assert "planner (achievable)" in r.stdout
    assert "Traceback" not in r.stderr and "KeyboardInterrupt" not in r.stderr, r.stderr


def test_the_oracle_phase_says_when_it_computes_and_is_silent_when_cached(tiny, tmp_path, monkeypatch):
    import io

    from asap_dsl.backends.compare.paired import _oracle
    from asap_dsl.cli.compare import SweepProgress

    monkeypatch.setenv("ASAP_CACHE_DIR", str(tmp_path / "cache"))
    prog = asap_dsl.load(tiny)
    heard = []
    first = _oracle(prog, "go", 6, 1, "rail R", lambda *a: heard.append(a))
    assert first is not None and heard[0] == ("rail R", 0, 6) and heard[-1] == ("rail R", 6, 6)
    heard.clear()
    assert _oracle(prog, "go", 6, 1, "rail R", lambda *a: heard.append(a)) is not None and heard == []  # cached
    stream = io.StringIO()
    shown = SweepProgress(1, stream)
    for k in (0, 3, 6):
        shown.oracle("rail R", k, 6)
    lines = stream.getvalue().splitlines()
    assert len(lines) == 2 and "computing the minima of 6 states" in lines[0] and "6 states in" in lines[1]


def test_the_replayed_ceiling_is_replayed_again_when_the_ceiling_changes(tiny, tmp_path, monkeypatch):
    """The oracle's (or planner's) replay is cached beside the report; a ceiling computed again
    (another planner budget, a new oracle) must not be judged by the old replay."""
    from asap_dsl.backends.compare.paired import _baseline
    from asap_dsl.backends.oracle.cache import CachedOracle, oracle_for
    from asap_dsl.sampling import task_states

    monkeypatch.setenv("ASAP_CACHE_DIR", str(tmp_path / "cache"))
    prog = asap_dsl.load(tiny)
    states = task_states(prog.system, prog.task("go").model, 6, seed=2024)
    oracle = oracle_for(prog, "go", 2024, 6, workers=1)
    first = _baseline(prog, "go", "oracle", states, oracle, tmp_path / "methods")
    assert _baseline(prog, "go", "oracle", states, oracle, tmp_path / "methods") == first  # read back
    worse = [dict(s, actions=None, steps=None) if i == 0 else s for i, s in enumerate(oracle.data["states"])]
    again = _baseline(prog, "go", "oracle", states, CachedOracle({**oracle.data, "states": worse}), tmp_path / "methods")
    assert len(list((tmp_path / "methods").glob("*.json"))) == 2
    assert again["per_state"]["t_reach"][0] is None and first["per_state"]["t_reach"][0] is not None


def test_the_results_readme_is_built_from_the_reports_numbers_and_the_papers_cells(tmp_path):
    """docs/results/README.md: the paper's cell beside ours (from report.json, which compare writes
    beside report.md) and the ceiling; a cell below the paper is listed; a benchmark without its
    report says so and how to make it."""
    import json
    import shutil

    from asap_dsl.backends.compare.paper import readme
    from asap_dsl.backends.compare.report import Method, ReportData, write
    from conftest import ROOT

    col = _column("bicycle", "oracle (local)", [4, 10, 15, 18, 20, 25, 12, 19, 13, 29])
    methods = [Method(f"{r}/sac", r, "rl", {col.name: [_ev(STEPS), _ev(STEPS)]}) for r in ("asap", "rho", "distance")]
    td3 = Method("asap/td3", "ASAP-Phi (td3)", "rl", {col.name: [_ev(STEPS)]})
    # the look-ahead's row (compare --lookahead): its own column, no paper cell
    refined = Method("asap/sac+lookahead", "ASAP-Phi (sac) + look-ahead 8", "lookahead",
                     {col.name: [_ev([4, 10, 15, 18, 20, 25, 12, 19, 13, 29])] * 2})
    paths = write(tmp_path / "bicycle", ReportData("t", [col], table1=methods + [refined], table2=[methods[0], td3],
                                                  runs=[], table2_tolerances=[20]))
    saved = json.loads(paths["json"].read_text())
    assert saved["table2"][1]["cells"][col.name]["20"]["mean"] == pytest.approx(0.5)
    shutil.copy(ROOT / "docs" / "results" / "paper.json", tmp_path / "paper.json")
    (tmp_path / "bicycle" / "made.json").write_text(json.dumps({"command": "bash scripts/results bicycle",
                                                                "wall_seconds": 1800, "machine": "2 cores"}))
    # the default preset's own report (ASAP-Phi, SAC): a column of its own, no paper cell
    best = Method("asap/sac", "ASAP-Phi (sac)", "rl", {col.name: [_ev([4, 10, 15, 18, 20, 25, 12, 19, 13, 14])] * 3})
    write(tmp_path / "bicycle" / "default", ReportData("t", [col], table1=[best], table2=[], runs=[]))
    text = readme(tmp_path)
    t1 = text.split("## Table 1")[1].split("## Table 2")[0]
    t2 = text.split("## Table 2")[1].split("## Where")[0]
    # bicycle R within 30: the paper's 92.8 / 80.6 / 78.4 beside ours (9 of 10 states) and the ceiling (10 of 10)
    assert ("| bicycle | R | 30 | 92.8 | 90.0 ± 0.0 | 80.6 | 90.0 ± 0.0 | 78.4 | 90.0 ± 0.0 | 100.0 ± 0.0 | 100.0 ± 0.0 "
            "| 100.0 |") in t1
    assert "| bicycle | R | 15 | 74.4 | 30.0 ± 0.0 | 72.6 | 30.0 ± 0.0 | 65.4 | 30.0 ± 0.0 | 50.0 ± 0.0 | 60.0 ± 0.0 |" in t1
    assert "| d reward paper | ours | ASAP-Phi + look-ahead, ours | ASAP-Phi, default preset | ceiling |" in t1
    assert "| bicycle, the default preset | [report](bicycle/default/report.md) |" in text
    assert "| bicycle | R | 20 | 83.0 | 50.0 ± 0.0 | 76.8 | 50.0 |" in t2  # SAC, then TD3 (one seed)
    assert "| dc_motor | R | 30 | 97.4 | — |" in t1 and "| 35.5 | — | — | — | — |" in t1  # no report yet
    assert "Table 1, bicycle R within 30, ASAP-Phi: ours 90.0 ± 0.0 against 92.8" in text
    assert "Table 1, bicycle R within 30, ρ reward" not in text  # ours, 90.0, is above the paper's 80.6
    assert "| bicycle | [report](bicycle/report.md) | `bash scripts/results bicycle` | — | — | 30 min | 2 cores |" in text
    assert "`bash scripts/results dc_motor attitude swimmer` makes them" in text
    # the README's headline (ASAP-Phi with SAC beside the ceiling and the paper) and its ceilings,
    # each between its own markers only
    from asap_dsl.backends.compare.paper import CEILINGS_END, CEILINGS_START, HEADLINE_END, HEADLINE_START, main

    (tmp_path / "README.md").write_text(f"# x\nbefore\n{HEADLINE_START}\nold table\n{HEADLINE_END}\nmiddle\n"
                                        f"{CEILINGS_START}\nold ceilings\n{CEILINGS_END}\nafter\n")
    assert main([str(tmp_path), "--readme", str(tmp_path / "README.md")]) == 0
    new = (tmp_path / "README.md").read_text()
    assert new.startswith("# x\nbefore\n") and new.endswith(f"{CEILINGS_END}\nafter\n")
    assert f"{HEADLINE_END}\nmiddle\n{CEILINGS_START}\n" in new
    assert "old table" not in new and "old ceilings" not in new
    # the ceiling the report stands beside, 10 of 10 states within 30, with its Wilson interval
    assert "| bicycle | R | oracle (local) | 10 | 30 / 25 / 15 | 100.0 [72.2, 100.0] / " in new
    assert "| dc_motor | R | not yet made | — | — | — |" in new
    assert "| bicycle | R | 30 / 25 / 15 | 100.0 / 100.0 / 60.0 | 90.0 / " in new  # the default's, then the learner's
    assert "| 100.0 / 90.0 / 50.0 | 100.0 / 90.0 / 50.0 |" in new
    assert "| dc_motor | R | 30 / 25 / 15 | — | not yet made | — | — | 97.4 / 95.2 / 89.0 |" in new
    (tmp_path / "README.md").write_text("no markers\n")
    assert main([str(tmp_path), "--readme", str(tmp_path / "README.md")]) == 1


def test_a_report_names_its_specs_relative_to_the_working_directory(tmp_path, monkeypatch):
    """A committed report.json named the snapshot's absolute directory (/work/exp/snapK/specs/...)."""
    from asap_dsl.backends.compare.report import _portable

    (tmp_path / "specs").mkdir()
    monkeypatch.chdir(tmp_path)
    assert _portable(str(tmp_path / "specs" / "bicycle.asap")) == "specs/bicycle.asap"
    assert _portable("specs/bicycle.asap") == "specs/bicycle.asap"
    elsewhere = str(tmp_path.parent / "other.asap")
    assert _portable(elsewhere) == elsewhere
