"""Example trajectories in the state space: the projection chosen from the spec (benchmarks and
small specs), the regions drawn on it, the PNG, and ``asapc eval --plot`` on a tiny trained run."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

import asap_dsl
from asap_dsl.backends.compare.phase_plots import (DPI, LEGEND, LINE, MIN_WIDTH, PANEL, Example, choose_projection, scene,
                                                   state_space)
from conftest import RAIL, ROOT, asapc, one_line_error


def _pairs(prog, task: str) -> list[tuple]:
    names = prog.system.state_names
    proj = choose_projection(prog.system, prog.task(task).model, prog.regions)
    return [("step" if a is None else names[a], names[b]) for a, b in proj.pairs]


@pytest.mark.parametrize("spec, pair", [("dc_motor", ("theta", "omega")), ("bicycle", ("x", "y")),
                                        ("swimmer", ("x", "y"))])
def test_the_benchmarks_project_on_the_coordinates_that_show_the_task(spec, pair):
    prog = asap_dsl.load(ROOT / "specs" / f"{spec}.asap")
    for task in prog.tasks:
        assert _pairs(prog, task) == [pair], (spec, task)


SMALL = """\
system Small {
  state a in [-10, 10] init [-1, 1]
  state b in [-10, 10] init [-1, 1]
  state c in [-1, 1]   init [-0.1, 0.1]
  action u in [-1, 1]
  let r = a + c
  dt = 0.1
  ode { a' = r  b' = u  c' = u }
}
region g2 = ball([5, -4, 0], 1)
region g1 = ball({a: 6}, 0.5)
region home = ball([0, 0, 0], 0.5)
region wall = box(b in [3, inf])
region cone = ball({r: 0}, 0.2)
task two { asap in g2  deadline 20 }
task one { asap in g1  avoid in wall  deadline 20 }
task partner { asap in g1  deadline 20 }
task spread { asap in home or in cone  deadline 20 }
"""


def test_projection_rules_on_a_small_spec():
    prog = asap_dsl.loads(SMALL)
    assert _pairs(prog, "two") == [("a", "b")]             # both offsets lead
    assert _pairs(prog, "one") == [("a", "b")]             # one leader; the wall lies along b
    assert _pairs(prog, "partner") == [("a", "c")]         # a' = r = a + c: c, through the let
    assert _pairs(prog, "spread") == [("a", "b"), ("a", "c"), ("b", "c")]  # goal at the box's centre: its spread
    assert _pairs(asap_dsl.loads(RAIL), "go") == [("step", "x")]           # one state: against the step


def test_regions_are_drawn_as_their_projections():
    prog = asap_dsl.loads(SMALL)
    one = scene(prog.system, prog.task("one").model, prog.regions)
    goal, wall = one.shapes[0]
    # g1 constrains a only: a band along b; the wall constrains b only, unbounded above
    assert (goal.kind, goal.x, goal.y) == ("rect", (5.5, 6.5), (-np.inf, np.inf))
    assert (wall.role, wall.kind, wall.x, wall.y) == ("unsafe", "rect", (-np.inf, np.inf), (3.0, np.inf))
    two = scene(prog.system, prog.task("two").model, prog.regions)
    (disc,) = two.shapes[0]
    assert (disc.kind, disc.centre, disc.radius) == ("disc", (5.0, -4.0), 1.0)  # same radius, projected centre
    spread = scene(prog.system, prog.task("spread").model, prog.regions)
    assert any("cone is over r" in n for n in spread.notes)          # a let: not drawn, said
    assert any("not how they combine" in n for n in spread.notes)    # a union: its regions drawn, said


def _png_size(png: bytes) -> tuple[int, int]:
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and png[12:16] == b"IHDR"
    return struct.unpack(">II", png[16:24])


def test_the_picture_is_a_png_of_the_expected_size():
    prog = asap_dsl.loads(SMALL)
    rng = np.random.default_rng(0)

    def ex(task: str, oracle: bool) -> Example:
        sc = scene(prog.system, prog.task(task).model, prog.regions)
        paths = [np.cumsum(rng.normal(size=(12, 3)), axis=0) for _ in range(3)]
        return Example(task, "sac", sc, paths, [11, None, 4], oracle=paths[::-1] if oracle else None,
                       oracle_reach=[3, 5, None] if oracle else [], missing="no oracle")

    png = state_space([ex("two", True), ex("spread", False)])
    width, height = _png_size(png)
    assert width == round(max(MIN_WIDTH, 3 * PANEL[0]) * DPI) >= 900  # three pairs: the grid of the spread's three coordinates
    lines = height / DPI - 2 * PANEL[1] - LEGEND  # two rows, the legend, the caption's lines
    assert 3 <= round(lines / LINE) <= 8, lines
    assert state_space([]) is None
    one = _png_size(state_space([ex("two", True)]))  # a single pair: still wide enough to read
    assert one[0] == round(MIN_WIDTH * DPI) >= 900


def test_eval_plot_writes_the_picture_and_a_bad_path_is_one_sentence(tiny, tmp_path, capsys):
    run = tmp_path / "run"
    asap_dsl.train(tiny, steps=100, n_envs=2, out=run, settings={"net_arch": [16, 16], "learning_starts": 32,
                                                                  "batch_size": 32},
                   evaluate=False, demonstrations=0, engine="sb3")  # quick: no oracle, no JAX compilation
    code, out, err = asapc(capsys, "eval", run, "--episodes", 20, "--workers", 1, "--plot")
    png = run / "plots" / "trajectories.png"
    assert code == 0, err
    assert f"plot: {png}" in out and _png_size(png.read_bytes())[0] > 0
    code, out, err = asapc(capsys, "eval", run, "--episodes", 20, "--format", "json", "--plot", tmp_path / "p.png")
    assert code == 0, err
    assert json.loads(out)["plot"] == str(tmp_path / "p.png") and (tmp_path / "p.png").is_file()
    for bad, words in ((tiny / "x.png", "cannot write"), (tmp_path / "p.pdf", "ending in .png")):
        code, out, err = asapc(capsys, "eval", run, "--episodes", 20, "--plot", bad)
        assert code == 1 and words in one_line_error(err), err
        assert "within" in out  # the evaluation is shown all the same


def test_bold_marks_a_real_best_only():
    from asap_dsl.backends.compare.report import Column, Method, table_rows

    def method(key: str, rates: dict, kind: str = "rl") -> Method:
        ev = {"rows": [{"tolerance": T, "rate": r, "count": round(r * 100), "states": 100} for T, r in rates.items()]}
        return Method(key, key, kind, {"c R": [ev]})

    col = Column("c.asap", "reach", [30, 15], 30)
    methods = [method("a", {30: 0.8, 15: 0.0}), method("b", {30: 0.6, 15: 0.0}), method("g", {30: 0.8, 15: 0.0}, "greedy")]
    rows = {(r[0], r[1]): r[2] for r in table_rows(methods, [col], md=True)}
    assert rows[("30", "a")].startswith("**") and rows[("30", "g")].startswith("**")  # tied at the top: both best
    assert not rows[("30", "b")].startswith("**")
    assert not any(rows[("15", m)].startswith("**") for m in "abg")  # every 0.0: no bold
    alone = table_rows([method("a", {30: 0.5, 15: 0.1})], [col], md=True)
    assert not any(r[2].startswith("**") for r in alone)  # one method: nothing to be best against
