"""Every example of LANGUAGE.md parses, checks and means what the text says.

The blocks are read from LANGUAGE.md itself: the whole-file example as it is, the formula
snippet inside a small system with the states and regions it names, and the task template
turned into concrete variants (one per alternative its comments describe).
"""

from __future__ import annotations

import re

import pytest

import asap_dsl
from asap_dsl.stl import ir
from conftest import ROOT, language_blocks

BLOCKS = language_blocks()
WHOLE_FILE = next(b for b in BLOCKS if b.lstrip().startswith("# specs/dc_motor.asap"))
FORMULAS = next(b for b in BLOCKS if b.lstrip().startswith("formula "))
TASK_TEMPLATE = next(b for b in BLOCKS if b.lstrip().startswith("task NAME"))

# The system the snippets need: omega (settle), regions goal and unsafe.
HOST = """
system Host {
  state theta in [-4, 4]
  state omega in [-10, 10]
  action V in [-1, 1]
  dt = 0.1
  ode { theta' = omega  omega' = V }
}
region goal   = ball([1, 0], 0.5)
region unsafe = ball([-1, 0], 0.2)
"""


def test_language_md_has_the_expected_blocks():
    assert len(BLOCKS) >= 3
    assert "system DCMotor" in WHOLE_FILE and "task reach_avoid" in WHOLE_FILE


def test_whole_file_example_checks_as_is():
    prog = asap_dsl.loads(WHOLE_FILE, name="dc_motor.asap")
    assert prog.system.name == "DCMotor"
    assert prog.system.state_names == ("theta", "omega", "i")
    assert prog.system.action_names == ("V",)
    assert prog.system.dt == pytest.approx(0.1)
    assert prog.system.integrator.method == "exact"
    assert prog.tasks == ("reach", "reach_avoid")
    reach = prog.task("reach")
    assert reach.deadline == 30 and reach.tolerances == (30, 25, 15)
    assert reach.avoid is None
    ra = prog.task("reach_avoid")
    assert ra.avoid is not None and ra.train == {"algo": "sac", "steps": 200000}
    assert ra.spec.text == "(eventually[0, 30] in goal) and (always[0, 30] (not in unsafe))"
    # init defaults to the state space unless given; -pi..pi for theta
    theta = prog.system.states[0]
    assert (theta.low, theta.high) == (-4, 4)
    assert theta.init_low == pytest.approx(-3.141592653589793)
    assert prog.warnings == []


def test_formula_block_checks_and_means_what_it_says():
    prog = asap_dsl.loads(HOST + FORMULAS + "\ntask t { asap reached  avoid in unsafe  deadline 40 }")
    assert prog.formulas == ("reached", "safe", "settle")
    assert prog.formula("reached").text == "in goal"
    assert prog.formula("safe").text == "always[0, inf] (not in unsafe)"
    # 3s at dt 0.1 is 30 steps; the inner window is 5 steps
    assert prog.formula("settle").text == "eventually[0, 30] (historically[0, 5] abs(omega) < 0.1)"
    node = prog.formula("settle").ir
    assert isinstance(node, ir.Eventually) and node.interval == ir.Interval(0, 30)
    assert isinstance(node.arg, ir.Historically) and node.arg.interval == ir.Interval(0, 5)


def _template_lines():
    """The task template with comments removed, one clause per line: {keyword: line}."""
    out = {}
    for line in TASK_TEMPLATE.splitlines():
        code = line.split("#", 1)[0].strip()
        if not code or code.startswith("task") or code == "}":
            continue
        out[code.split()[0]] = code
    return out


def test_task_template_lists_every_clause():
    assert set(_template_lines()) == {"asap", "avoid", "deadline", "tolerances", "episode", "reward", "r_sat",
                                      "observe", "train"}


def _concrete(**replace) -> str:
    """The template made concrete: FORMULA and N replaced, then clauses replaced by keyword."""
    clauses = _template_lines()
    clauses["asap"] = "asap in goal"
    clauses["avoid"] = "avoid in unsafe"
    clauses["deadline"] = "deadline 30"
    clauses["tolerances"] = "tolerances 30, 25, 15"
    clauses["episode"] = "episode 20..30"
    clauses["train"] = clauses["train"].replace(", ...", "")
    for key, value in replace.items():
        if value is None:
            clauses.pop(key)
        else:
            clauses[key] = value
    body = "\n  ".join(clauses.values())
    return HOST + "task NAME {\n  " + body + "\n}\n"


def _task(**replace):
    return asap_dsl.loads(_concrete(**replace)).task("NAME")


def test_task_template_defaults_as_written():
    t = _task()
    assert t.reward.kind == "asap"
    assert t.r_sat is None
    assert t.observe == ("state",)
    assert t.episode == (20, 30)
    assert t.tolerances == (30, 25, 15)
    assert t.train == {"algo": "sac", "steps": 1000000, "seed": 0}


@pytest.mark.parametrize("reward, kind, params", [
    ("reward asap", "asap", {}),
    ("reward rho", "rho", {}),
    ("reward rho(window = 5)", "rho", {"window": 5}),
    ("reward distance(lambda_t = 1, lambda_o = 1, base = 0)", "distance", {"lambda_t": 1.0, "lambda_o": 1.0, "base": 0.0}),
    ("reward distance", "distance", {"lambda_t": 1.0, "lambda_o": 1.0, "base": 0.0}),
    ("reward distance(lambda_t = 2)", "distance", {"lambda_t": 2.0, "lambda_o": 1.0, "base": 0.0}),
])
def test_task_reward_variants(reward, kind, params):
    t = _task(reward=reward)
    assert t.reward.kind == kind
    assert dict(t.reward.params) == params


@pytest.mark.parametrize("r_sat, value", [("r_sat auto", None), ("r_sat 100", 100.0), ("r_sat 2.5e3", 2500.0)])
def test_task_r_sat_variants(r_sat, value):
    assert _task(r_sat=r_sat).r_sat == value


@pytest.mark.parametrize("observe, items", [("observe state", ("state",)), ("observe state, time", ("state", "time"))])
def test_task_observe_variants(observe, items):
    assert _task(observe=observe).observe == items


def test_task_deadline_in_seconds_and_defaults():
    t = _task(deadline="deadline 3s", tolerances=None, episode=None)
    assert t.deadline == 30
    assert t.tolerances == (30,)          # default: the deadline
    assert t.episode == (30, 30)          # default: deadline..deadline
    assert _task(deadline="deadline 2500ms", tolerances="tolerances 25, 1s", episode="episode 1s..2s").tolerances == (25, 10)


def test_task_minimal_defaults():
    t = _task(avoid=None, tolerances=None, episode=None, reward=None, r_sat=None, observe=None, train=None)
    assert t.avoid is None and t.reward.kind == "asap" and t.r_sat is None
    assert t.observe == ("state",) and t.train == {} and t.episode == (30, 30)
    assert t.spec.text == "eventually[0, 30] in goal"


def test_language_md_precedence_sentence():
    src = HOST + "formula f = eventually[0, 30] in goal and always not in unsafe\ntask t { asap in goal deadline 30 }"
    f = asap_dsl.loads(src).formula("f")
    assert f.text == "(eventually[0, 30] in goal) and (always[0, inf] (not in unsafe))"
    assert isinstance(f.ir, ir.And)
    assert isinstance(f.ir.left, ir.Eventually) and isinstance(f.ir.right, ir.Always)
    assert isinstance(f.ir.right.arg, ir.Not)


def test_interval_examples_in_seconds():
    src = HOST + "formula a = eventually[0, 1.5s] in goal\nformula b = always[0, 500ms] in goal\n" \
                 "formula c = once in goal\ntask t { asap in goal deadline 30 }"
    prog = asap_dsl.loads(src)
    assert prog.formula("a").ir.interval == ir.Interval(0, 15)
    assert prog.formula("b").ir.interval == ir.Interval(0, 5)
    assert prog.formula("c").ir.interval == ir.Interval(0, None)   # no interval: [0, inf]


def test_number_and_constant_lexemes():
    src = HOST.replace("dt = 0.1", "dt = 1e-1") + "formula f = theta < 2.5e-3 + pi - e and omega < inf\ntask t { asap f deadline 30 }"
    prog = asap_dsl.loads(src)
    assert prog.system.dt == pytest.approx(0.1)
    assert re.search(r"2\.5e-3", prog.formula("f").text)


def test_vendored_language_md_matches_the_contract():
    """tests/data/LANGUAGE.md stands in for ../shared/design/LANGUAGE.md where that is absent."""
    from conftest import SHARED_LANGUAGE_MD, VENDORED_LANGUAGE_MD

    if not SHARED_LANGUAGE_MD.is_file():
        pytest.skip("no ../shared/design/LANGUAGE.md beside this checkout")
    assert VENDORED_LANGUAGE_MD.read_text(encoding="utf-8") == SHARED_LANGUAGE_MD.read_text(encoding="utf-8"), (
        "the contract changed: copy ../shared/design/LANGUAGE.md to tests/data/LANGUAGE.md and check the examples")


def test_the_docs_stand_alone():
    """The project's docs are read without the design notes: none of them defers to those."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    for page in pages:
        text = page.read_text(encoding="utf-8")
        for name in ("LANGUAGE.md", "BENCHMARKS.md", "ARCHITECTURE.md", "design notes", "../shared"):
            assert name not in text, f"{page.name} refers to {name}"
    for doc in ("language.md", "benchmarks.md", "cli.md", "limits.md", "oracle.md", "training.md", "compare.md"):
        assert f"docs/{doc}" in (ROOT / "README.md").read_text(encoding="utf-8") or doc in "".join(
            p.read_text(encoding="utf-8") for p in pages), f"nothing links {doc}"


def test_the_readme_tour_lints_clean():
    import re

    import asap_dsl

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    (tour,) = re.findall(r"```\n(system Cart.*?)```", readme, re.S)
    prog = asap_dsl.loads(tour, "tour.asap")
    assert not prog.warnings and set(prog.tasks) == {"park", "recover"}
    assert prog.task("recover").model.init_box is not None
