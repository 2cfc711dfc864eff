"""`asapc lint` and `asapc show`: exit codes, output formats, and no traceback on bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from asap_dsl import cli
from conftest import ROOT, asapc

SPECS = sorted(str(p) for p in (ROOT / "specs").glob("*.asap"))
EXAMPLE = str(ROOT / "examples" / "double_integrator.asap")
BROKEN = str(ROOT / "examples" / "broken.asap")


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_lint_benchmark_specs_and_example_pass(capsys):
    code, out, _ = run(capsys, "lint", *SPECS, EXAMPLE)
    assert code == 0
    assert f"{len(SPECS) + 1} files checked: 0 errors" in out


def test_lint_broken_example_reports_every_error_at_once(capsys):
    code, out, _ = run(capsys, "lint", BROKEN)
    assert code == 1
    for c in ("E101", "E104", "E106", "E107", "E108", "E111", "E115"):
        assert c in out
    # positioned, with the line and a caret
    assert f"{BROKEN}:20:17: error E101 unknown-name: unknown region 'hom'" in out
    assert "did you mean 'home'?" in out
    assert "^^^" in out


def test_lint_json_is_machine_readable(capsys):
    code, out, _ = run(capsys, "lint", "--format", "json", BROKEN)
    assert code == 1
    data = json.loads(out)
    assert data["errors"] == 7
    first = data["diagnostics"][0]
    assert set(first) >= {"code", "name", "severity", "message", "file", "line", "column", "end_line", "end_column"}
    lines = [(d["line"], d["column"]) for d in data["diagnostics"]]
    assert lines == sorted(lines)


def test_lint_strict_fails_on_warnings_only(capsys):
    spec = str(ROOT / "specs" / "bicycle.asap")  # W201: the paper's balls overlap
    assert run(capsys, "lint", spec)[0] == 0
    assert run(capsys, "lint", "--strict", spec)[0] == 1


@pytest.mark.parametrize("make", ["missing", "directory", "binary", "empty"])
def test_lint_bad_files_are_positioned_errors(capsys, tmp_path, make):
    path = tmp_path / "x.asap"
    if make == "directory":
        path.mkdir()
    elif make == "binary":
        path.write_bytes(b"\xff\xfe\x00garbage")
    elif make == "empty":
        path.write_text("  \n")
    code, out, err = run(capsys, "lint", str(path))
    assert code == 1
    assert "E002" in out and str(path) in out
    assert "Traceback" not in out + err


def test_show_prints_the_full_specification(capsys):
    code, out, _ = run(capsys, "show", str(ROOT / "specs" / "dc_motor.asap"))
    assert code == 0
    assert "(eventually[0, 30] in goal) and (always[0, 30] (not in unsafe))" in out
    assert "rho bounds" in out and "r_sat" in out and "horizon        30 steps" in out
    for name in ("theta", "omega", "i", "V", "goal", "unsafe", "reach", "reach_avoid"):
        assert name in out


def test_show_json_r_sat_satisfies_the_theorem(capsys):
    code, out, _ = run(capsys, "show", "--format", "json", str(ROOT / "specs" / "dc_motor.asap"))
    assert code == 0
    data = json.loads(out)
    task = data["tasks"]["reach"]
    lo, hi = task["rho_bounds"]
    scale = task["rho_scale"]
    k_max = task["episode"][1]
    assert scale == pytest.approx(1 / (hi - lo))
    assert task["r_sat"] > hi * scale + (hi - lo) * scale * k_max


def test_show_unknown_task_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["show", "--task", "rech", str(ROOT / "specs" / "dc_motor.asap")])
    assert info.value.code == 2
    assert "did you mean 'reach'?" in capsys.readouterr().err


def test_show_spec_with_errors_exits_1_with_the_report(capsys):
    code, out, err = run(capsys, "show", BROKEN)
    assert code == 1
    assert "E101" in err and "Traceback" not in err


def test_console_script_bad_flag_no_traceback():
    proc = subprocess.run([sys.executable, "-m", "asap_dsl.cli", "lint", "--no-such-flag", EXAMPLE],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert "unrecognized arguments" in proc.stderr and "Traceback" not in proc.stderr


_CART = """
system Cart {
  state p in [-10, 10] init [INIT]
  state v in [-5, 5]   init [0, 0]
  action u in [-1, 1]
  dt = 0.5
  integrator exact
  ode { p' = v  v' = u }
}
region home = ball([0, 0], 0.2)
task park { asap in home  deadline 6 }
"""


@pytest.mark.parametrize("init, fires", [("-0.1, 0.1", False), ("8, 9", True)])
def test_lint_deep_warns_when_the_deadline_is_infeasible(capsys, tmp_path, init, fires):
    """W208: from p = 8 a unit acceleration needs far more than 6 steps of 0.5 s to park."""
    spec = tmp_path / "cart.asap"
    spec.write_text(_CART.replace("INIT", init))
    code, out, _ = run(capsys, "lint", "--deep", "--samples", "4", str(spec))
    assert code == 0  # a warning, not an error
    assert ("W208" in out) == fires
    if fires:
        assert "4 of 4 sampled initial states of task 'park'" in out and "proved by a convex problem" in out


def test_show_json_is_strict_json_with_unbounded_values(capsys, tmp_path):
    spec = tmp_path / "free.asap"
    spec.write_text("system A { state x in [-1e300, 1e300]  action u in [-1, 1]  dt = 1  map { x = x + u } }\n"
                    "formula up = once x > 0\nregion g = ball([0], 1)\ntask t { asap in g  deadline 3 }")
    code, out, _ = run(capsys, "show", "--format", "json", str(spec))
    assert code == 0
    data = json.loads(out, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))
    assert data["tasks"]["t"]["rho_bounds"] == ["-inf", 1.0]


def test_only_regular_files_of_bounded_size_are_read(capsys, tmp_path, monkeypatch):
    """/dev/zero never ends and a FIFO blocks: both are refused before anything is read."""
    import os

    from asap_dsl.limits import LIMITS

    fifo = tmp_path / "pipe.asap"
    os.mkfifo(fifo)
    for path in ("/dev/zero", str(fifo)):
        code, out, _ = run(capsys, "lint", path)
        assert code == 1 and "E002" in out and "not a regular file" in out
    big = tmp_path / "big.asap"
    big.write_text((ROOT / "examples" / "double_integrator.asap").read_text() + ("# padding\n" * 120_000))
    monkeypatch.setattr(LIMITS, "spec_bytes", LIMITS.spec_bytes)  # restored after the test
    code, out, _ = run(capsys, "--max-spec-size", "1", "lint", str(big))
    assert code == 1 and "larger than the limit of 1 MB" in out and "--max-spec-size" in out
    code, out, _ = run(capsys, "--max-spec-size", "2", "lint", str(big))
    assert code == 0, out
    with pytest.raises(SystemExit) as exit_:  # a size past any file: a usage error, not an overflow
        cli.main(["--max-spec-size", "99999999999999999999", "lint", str(big)])
    assert exit_.value.code == 2 and "at most 1,048,576 MB" in capsys.readouterr().err


def test_a_utf8_byte_order_mark_is_skipped(capsys, tmp_path):
    spec = tmp_path / "bom.asap"
    spec.write_bytes(b"\xef\xbb\xbf" + (ROOT / "examples" / "double_integrator.asap").read_bytes())
    code, out, _ = run(capsys, "lint", str(spec))
    assert code == 0, out


@pytest.mark.parametrize("argv, words", [
    (["--workers", "1000"], "more than the"),
    (["--seed", "-1"], "a seed is between 0 and 2^32 - 1"),
    (["--episodes", "1000000000"], "at most 1,000,000 initial states"),
    (["--task", ""], "--task needs a task name"),
])
def test_oracle_flags_that_would_exhaust_the_machine_are_refused(capsys, argv, words):
    try:
        code = cli.main(["oracle", str(ROOT / "specs" / "dc_motor.asap"), *argv])
    except SystemExit as e:
        code = e.code
    _, err = capsys.readouterr()
    assert code == 2 and words in err and "Traceback" not in err


def test_control_characters_and_huge_lines_never_reach_the_terminal_raw(capsys, tmp_path):
    spec = tmp_path / "esc.asap"
    src = (ROOT / "examples" / "double_integrator.asap").read_text()
    # an unknown region whose name line also holds a terminal escape in a comment, and a 2 MB line
    src = src.replace("asap       in home and stopped", "asap       in hom\x1b[2J and stopped  # \x1b]0;pwned\x07")
    src += "# " + "x" * 2_000_000 + " ¤\n" + "region wide = ball([0, 0], 1) " + "+" * 10 + "\n"
    spec.write_text(src)
    code, out, _ = run(capsys, "lint", str(spec))
    assert code == 1
    assert "\x1b" not in out and "\x07" not in out and "\\x1b" in out
    assert len(out) < 20_000  # excerpts are cut around the problem
    for line in out.splitlines():
        assert len(line) < 400
    code, out, _ = run(capsys, "show", str(ROOT / "examples" / "double_integrator.asap"))
    assert code == 0 and "\x1b" not in out


# ---------------------------------------------------------------- one voice
def test_an_unknown_task_is_exit_2_with_one_wording_in_every_command(capsys, tmp_path):
    spec = str(ROOT / "specs" / "dc_motor.asap")
    for argv in (["show", spec, "--task", "reac"], ["oracle", spec, "--task", "reac"],
                 ["train", spec, "--task", "reac", "--out", str(tmp_path / "r")]):
        with pytest.raises(SystemExit) as stop:
            code = cli.main(argv)
            raise SystemExit(code)
        err = capsys.readouterr().err
        assert stop.value.code == 2, argv
        assert f"asapc: error: no task named 'reac' in {spec}; did you mean 'reach'?" in err, (argv, err)


def test_version_flag_short_and_long(capsys):
    for flag in ("-V", "--version"):
        with pytest.raises(SystemExit) as stop:
            cli.main([flag])
        assert stop.value.code == 0 and capsys.readouterr().out.startswith("asapc ")


def test_show_json_has_one_shape_with_the_diagnostics_inside(capsys, tmp_path):
    import json

    code, out, _ = run(capsys, "show", "--format", "json", str(ROOT / "examples" / "double_integrator.asap"))
    d = json.loads(out)
    assert code == 0 and {"file", "errors", "warnings", "diagnostics", "system", "tasks"} <= set(d)
    assert all(isinstance(v, str) and not v.isdigit() for v in d["system"]["lets"].values())  # expressions
    for t in d["tasks"].values():
        assert isinstance(t["horizon_steps"], int) and isinstance(t["deadline_steps"], int)
    warned = tmp_path / "warned.asap"
    warned.write_text((ROOT / "examples" / "double_integrator.asap").read_text() + "\nregion spare = ball([0, 0], 1)\n")
    code, out, _ = run(capsys, "show", "--format", "json", str(warned))
    d = json.loads(out)
    assert code == 0 and d["warnings"] == 1 and d["diagnostics"][0]["code"] == "W202"
    code, out, _ = run(capsys, "show", "--format", "json", str(ROOT / "examples" / "broken.asap"))
    d = json.loads(out)
    assert code == 1 and d["errors"] == 7 and "system" not in d and d["diagnostics"][0]["severity"] == "error"


def test_lint_deep_says_what_it_did_not_check(capsys, tmp_path):
    import json

    spec = tmp_path / "two.asap"
    spec.write_text("system Rail {\n  state x in [-5, 5]\n  action u in [-1, 1]\n  dt = 0.1\n  ode { x' = u }\n}\n"
                    "region g = ball([1], 0.5)\ntask plain { asap in g  deadline 100 }\n"
                    "task dwell { asap in g since x > 0.9  deadline 100 }\n")
    code, out, _ = run(capsys, "lint", "--deep", "--samples", "2", str(spec))
    assert code == 0 and "--deep did not check task 'dwell'" in out and "`since`" in out
    code, out, _ = run(capsys, "lint", "--deep", "--samples", "2", "--format", "json", str(spec))
    assert [s["task"] for s in json.loads(out)["deep_skipped"]] == ["dwell"]
    code, out, _ = run(capsys, "lint", "--deep", "--samples", "2", str(ROOT / "specs" / "swimmer.asap"))
    assert "black-box simulator" in out


def test_an_empty_task_is_exit_2_with_one_wording_in_every_command(capsys, tmp_path):
    spec = str(ROOT / "specs" / "dc_motor.asap")
    for argv in (["show", spec, "--task", ""], ["oracle", spec, "--task", ""],
                 ["train", spec, "--task", "", "--out", str(tmp_path / "r")]):
        with pytest.raises(SystemExit) as stop:
            raise SystemExit(cli.main(argv))
        assert stop.value.code == 2 and "asapc: error: --task needs a task name" in capsys.readouterr().err, argv


def test_an_empty_path_is_exit_2_and_nothing_is_written(capsys, tmp_path, monkeypatch):
    """Found by the hostile review: `compare --out ""` ran a sweep in the current directory (its
    lock and runs there), `eval --spec ""` said "this is a directory"."""
    monkeypatch.chdir(tmp_path)
    spec = str(ROOT / "specs" / "dc_motor.asap")
    for argv in (["compare", spec, "--out", ""], ["compare", spec, "--summaries", ""], ["train", spec, "--out", ""],
                 ["lint", ""], ["show", ""], ["oracle", ""], ["eval", ""], ["export", ""],
                 ["eval", str(tmp_path), "--spec", ""], ["export", str(tmp_path), "--out", ""], ["tune", spec, "--out", ""]):
        code, _, err = asapc(capsys, *argv)
        assert code == 2 and "expected a path, got an empty text" in err, (argv, err)
    assert list(tmp_path.iterdir()) == []
