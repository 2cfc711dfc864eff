"""The public Python API: load/loads, SpecError and Diagnostic, Program, Formula, Task; files that
cannot be read (E002); simulator factories that are named but never imported while checking."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest

import asap_dsl
from asap_dsl import Diagnostic, SpecError
from conftest import BASE, SPECS

EXPECTED_STATES = {
    "dc_motor": ("theta", "omega", "i"),
    "bicycle": ("x", "y", "psi", "v"),
    "attitude": ("w1", "w2", "w3", "p1", "p2", "p3"),
    "swimmer": ("x", "y", "th_tip", "th_1", "th_2", "vx", "vy", "w_tip", "w_1", "w_2"),
}


def test_public_names():
    for name in ("load", "loads", "SpecError", "Diagnostic", "Program", "Formula", "Task"):
        assert hasattr(asap_dsl, name)


@pytest.mark.parametrize("path", SPECS, ids=lambda p: p.stem)
def test_specs_load(path):
    prog = asap_dsl.load(path)
    assert prog.system.state_names == EXPECTED_STATES[path.stem]
    assert prog.tasks == ("reach", "reach_avoid")
    assert prog.file == str(path)
    ra = prog.task("reach_avoid")
    assert ra.avoid is not None and ra.asap.causal and ra.avoid.causal
    assert ra.spec.horizon == ra.deadline
    assert set(ra.tolerances) <= set(range(1, ra.deadline + 1))


def test_dc_motor_api_as_documented(repo_root):
    prog = asap_dsl.load(repo_root / "specs" / "dc_motor.asap")
    assert prog.system.state_names == ("theta", "omega", "i")
    assert prog.tasks == ("reach", "reach_avoid")
    t = prog.task("reach_avoid")
    assert t.spec.text == "(eventually[0, 30] in goal) and (always[0, 30] (not in unsafe))"
    assert t.asap.text == "in goal" and t.avoid.text == "in unsafe"
    # robustness of the spec: [T, n] -> [T], [B, T, n] -> [B, T]
    trace = np.zeros((31, 3))
    trace[10:, 0] = np.pi / 2
    rho = t.spec.robustness(trace)
    assert rho.shape == (31,)
    assert rho[0] == pytest.approx(0.2 - np.pi / 4) or rho[0] <= 0.5
    assert t.spec.robustness(np.stack([trace, trace])).shape == (2, 31)
    assert t.asap.satisfied(trace)[10] and not t.asap.satisfied(trace)[9]
    assert t.asap.first_time(trace) == 10


def test_loads_name_and_warnings():
    prog = asap_dsl.loads(BASE, name="mine.asap")
    assert prog.file == "mine.asap" and prog.warnings == []
    assert prog.source == BASE


def test_formula_and_task_lookup():
    src = BASE + "formula reached = in goal\nformula safe = historically not in unsafe\n"
    src = src.replace("asap in goal", "asap reached").replace("avoid in unsafe", "avoid not safe")
    prog = asap_dsl.loads(src)
    assert prog.formulas == ("reached", "safe")
    assert prog.formula("reached").text == "in goal"
    assert prog.task("t").asap.text == "in goal"
    assert prog.task().name == "t"  # the only task
    with pytest.raises(KeyError, match="did you mean 'reached'"):
        prog.formula("reachd")
    with pytest.raises(KeyError, match="did you mean 't'|the file has: t"):
        prog.task("tt")
    with pytest.raises(KeyError, match="no formula named 'zzz'"):
        prog.formula("zzz")


def test_task_without_name_needs_a_single_task(repo_root):
    prog = asap_dsl.load(repo_root / "specs" / "bicycle.asap")
    with pytest.raises(KeyError, match="reach, reach_avoid"):
        prog.task()
    with pytest.raises(KeyError, match="did you mean 'reach_avoid'"):
        prog.task("reach_avoi")


def test_spec_error_fields():
    src = BASE.replace("asap in goal", "asap in gaol")
    with pytest.raises(SpecError) as info:
        asap_dsl.loads(src, name="f.asap")
    err = info.value
    assert isinstance(err, Exception)
    [d] = err.errors
    assert isinstance(d, Diagnostic)
    # with the typo, 'goal' is unused: the warning is reported along with the error, sorted by position
    assert [x.code for x in err.diagnostics] == ["W202", "E101"]
    fields = [f.name for f in dataclasses.fields(Diagnostic)]
    assert fields[:8] == ["code", "severity", "message", "file", "line", "column", "end_line", "end_column"]
    assert (d.code, d.severity, d.file, d.line, d.column, d.end_line, d.end_column) == \
        ("E101", "error", "f.asap", 14, 11, 14, 15)
    assert d.name == "unknown-name" and d.is_error
    assert d.as_dict()["code"] == "E101"
    report = str(err).split("\n", 3)[3]  # after the warning's three lines
    assert report.splitlines()[0].startswith("f.asap:14:11: error E101 unknown-name: unknown region 'gaol'")
    assert "  asap in gaol" in report
    assert "          ^^^^" in report
    assert "did you mean 'goal'?" in report
    assert err.errors == [d]


# ---------------------------------------------------------------- unreadable files (E002)

def _e002(path):
    with pytest.raises(SpecError) as info:
        asap_dsl.load(path)
    [d] = info.value.diagnostics
    assert d.code == "E002" and d.severity == "error" and d.file == str(path)
    str(info.value)  # formats
    return d


def test_missing_file(tmp_path):
    d = _e002(tmp_path / "nope.asap")
    assert "no such file" in d.message and d.line == 0


def test_directory(tmp_path):
    d = _e002(tmp_path)
    assert "directory" in d.message and d.line == 0


def test_invalid_utf8(tmp_path):
    p = tmp_path / "latin1.asap"
    p.write_bytes(b"system P {\n  state x\xe9 in [0, 1]\n}\n")
    d = _e002(p)
    assert "UTF-8" in d.message and (d.line, d.column) == (2, 10)


def test_nul_byte(tmp_path):
    p = tmp_path / "bin.asap"
    p.write_bytes(b"system P {\x00}")
    d = _e002(p)
    assert "NUL" in d.message and (d.line, d.column) == (1, 11)


@pytest.mark.parametrize("content", ["", "   \n\n  \t\n"])
def test_empty_file(tmp_path, content):
    p = tmp_path / "empty.asap"
    p.write_text(content)
    d = _e002(p)
    assert "empty" in d.message


def test_comment_only_file_is_not_e002(tmp_path):
    p = tmp_path / "c.asap"
    p.write_text("# nothing here\n")
    with pytest.raises(SpecError) as info:
        asap_dsl.load(p)
    assert [d.code for d in info.value.diagnostics] == ["E114"]


# ---------------------------------------------------------------- simulators are never imported

def _with_simulator(target: str) -> str:
    return BASE.replace("  ode {\n    x' = y\n    y' = u\n  }\n", f'  simulator "{target}"\n')


def test_unknown_simulator_module_checks_without_import():
    prog = asap_dsl.loads(_with_simulator("some_module_that_does_not_exist_xyz:factory"))
    assert prog.system.kind == "simulator"
    assert prog.system.simulator == "some_module_that_does_not_exist_xyz:factory"
    assert "some_module_that_does_not_exist_xyz" not in sys.modules


def test_side_effect_module_is_not_imported(tmp_path, monkeypatch):
    marker = tmp_path / "imported.txt"
    (tmp_path / "asap_evil_sim_mod.py").write_text(
        f"open({str(marker)!r}, 'w').write('imported')\nraise RuntimeError('must not be imported')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    prog = asap_dsl.loads(_with_simulator("asap_evil_sim_mod:make"))
    spec = tmp_path / "s.asap"
    spec.write_text(_with_simulator("asap_evil_sim_mod:make"))
    prog2 = asap_dsl.load(spec)
    assert prog.system.simulator == prog2.system.simulator == "asap_evil_sim_mod:make"
    assert prog.task("t").spec.text
    assert "asap_evil_sim_mod" not in sys.modules
    assert not marker.exists()


@pytest.mark.parametrize("target", ["", "  ", ":factory", "module:"])
def test_malformed_simulator_target(target):
    with pytest.raises(SpecError) as info:
        asap_dsl.loads(_with_simulator(target))
    assert [d.code for d in info.value.errors] == ["E117"]


def test_formula_monitor_matches_offline():
    prog = asap_dsl.loads(BASE + "formula f = historically[0, 3] x < 2\n")
    f = prog.formula("f")
    rng = np.random.default_rng(0)
    trace = rng.uniform(-3, 3, size=(2, 12, 2))
    offline = f.robustness(trace)
    mon = f.monitor(batch=2)
    online = np.stack([mon.update(trace[:, k]) for k in range(12)], axis=1)
    np.testing.assert_allclose(online, offline)


@pytest.mark.parametrize("newline", ["\r\n", "\r"])
def test_positions_are_right_with_windows_and_old_mac_line_endings(tmp_path, newline):
    src = "\n".join(["system S0 {", "  state x in [-1, 1]", "  action u in [-1, 1]", "  dt = 0.1",
                     "  ode { x' = u }", "}", "task t {", "  asap x > zz", "  deadline 10", "}", ""])
    p = tmp_path / "crlf.asap"
    p.write_bytes(src.replace("\n", newline).encode())
    with pytest.raises(asap_dsl.SpecError) as err:
        asap_dsl.load(p)
    d = [d for d in err.value.diagnostics if d.code == "E101"][0]
    assert (d.line, d.column) == (8, 12)


def test_a_chain_of_a_thousand_formulas_loads_and_runs():
    head = ("system Deep {\n  state x in [-1, 1] init [-0.5, 0.5]\n  action u in [-1, 1]\n  dt = 0.1\n"
            "  ode { x' = u }\n}\nregion g = ball([0.5], 0.1)\n")
    chain = "\n".join(f"formula f{i} = f{i - 1} and x > -2" if i else "formula f0 = in g" for i in range(1000))
    # declared last-first too: formulas are built in dependency order, never by recursion
    for formulas in (chain, "\n".join(reversed(chain.splitlines()))):
        prog = asap_dsl.loads(head + formulas + "\ntask t { asap f999  deadline 10 }\n")
        env = asap_dsl.make_vec_env(prog, num_envs=2, seed=0)
        env.reset()
        _, rewards, _, _ = env.step(np.zeros((2, 1)))
        assert np.isfinite(rewards).all()
    nested = "\n".join(f"formula f{i} = historically[0, 1] f{i - 1}" if i else "formula f0 = in g" for i in range(300))
    with pytest.raises(asap_dsl.SpecError) as err:
        asap_dsl.loads(head + nested + "\ntask t { asap f299  deadline 10 }\n")
    d = err.value.diagnostics[0]
    assert d.code == "E001" and "formula 'f201' nests 201 operators deep" in d.message
    assert (d.line, d.column) == (8 + 201, 9)  # at the formula where the limit is crossed


