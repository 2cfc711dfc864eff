"""Every diagnostic rule of ``asap_dsl.diagnostics.RULES``: a case that fires it (code, line and
column asserted) and a close valid variant that does not. W208 (lint --deep) is tested with the
deep lint; E002 (unreadable files) through ``asap_dsl.load`` in test_api.py."""

from __future__ import annotations

import re

import pytest

import asap_dsl
from asap_dsl.diagnostics import RULES
from asap_dsl.lint import LINT_RULES
from conftest import BASE, DOCS, codes, diagnostics, position

NOT_HERE = {"W208", "E002"}


def edit(*pairs: str) -> str:
    """BASE with each (old, new) replacement applied once; the old text must be there."""
    src = BASE
    for old, new in zip(pairs[::2], pairs[1::2]):
        assert old in src, old
        src = src.replace(old, new, 1)
    return src


# code -> (source that fires, text at the reported position, occurrence, close source that does not)
CASES = {
    "E001": (edit("[-5, 5]", "[-5 5]"), "5]", 0,
             edit("[-5, 5]", "[-5, 5,]".replace(",]", "]"))),
    "E101": (edit("asap in goal", "asap in gaol"), "gaol", 0, BASE),
    "E102": (edit("state y in", "state x in"), "x in", 1, BASE),
    "E103": (edit("asap in goal", "asap in x"), "x\n", 0, BASE),
    "E104": (edit("ball([1, 0], 0.5)", "ball([1], 0.5)"), "[1]", 0,
             edit("ball([1, 0], 0.5)", "ball({x: 1}, 0.5)")),
    "E105": (edit("asap in goal", "asap historically[3, 1] in goal"), "[3, 1]", 0,
             edit("asap in goal", "asap historically[1, 3] in goal")),
    "E106": (edit("asap in goal", "asap once[0, 0.15s] in goal"), "0.15s", 0,
             edit("asap in goal", "asap once[0, 0.2s] in goal")),
    "E107": (edit("asap in goal", "asap eventually[0, 5] in goal"), "eventually", 0,
             edit("asap in goal", "asap once[0, 5] in goal")),
    "E108": (edit("state x in [-5, 5]", "state x in [-5, 5] init [-6, 0]"), "[-6, 0]", 0,
             edit("state x in [-5, 5]", "state x in [-5, 5] init [-5, 0]")),
    "E109": (edit("    y' = u\n", ""), "ode", 0, BASE),
    "E110": (edit("    y' = u\n", "    y' = u\n    x' = u\n"), "x' = u", 0,
             edit("    y' = u\n", "    y' = u + x\n")),
    "E111": (edit("dt = 0.1", "dt = 0.1\n  integrator exact", "y' = u", "y' = u * x"), "integrator", 0,
             edit("dt = 0.1", "dt = 0.1\n  integrator exact", "y' = u", "y' = u + 2 * x")),
    "E112": (edit("deadline 30", "deadline 30\n  tolerances 30, 40"), "tolerances", 0,
             edit("deadline 30", "deadline 30\n  tolerances 30, 20")),
    "E113": (edit("ball([1, 0], 0.5)", "ball([10, 0], 0.5)"), "asap in goal", 0,
             edit("ball([1, 0], 0.5)", "ball([4, 0], 0.5)")),
    "E114": (edit("  deadline 30\n", ""), "t {\n  asap", 0, BASE),
    "E115": (edit("asap in goal", "asap x == 1"), "==", 0, edit("asap in goal", "asap abs(x - 1) <= 0.1")),
    "E116": (edit("asap in goal", "asap x"), "x\n", 0, edit("asap in goal", "asap x > 0")),
    "E117": (edit("dt = 0.1", "dt = 0"), "0\n", 0, edit("dt = 0.1", "dt = 0.05")),
    "E118": (edit("y' = u", "y' = sni(x) + u"), "sni", 0, edit("y' = u", "y' = sin(x) + u")),
    "E119": (edit("dt = 0.1", "dt = 0.1\n  const a = 1; b = 2\n  let z = a * b * x", "asap in goal", "asap in goal and z > 0"),
             "b = 2", 0,
             edit("dt = 0.1", "dt = 0.1\n  const a = 1, b = 2\n  let z = a * b * x", "asap in goal", "asap in goal and z > 0")),
    "E120": (edit("dt = 0.1", "dt = 0.1\n  let p = q + 1\n  let q = p * x", "asap in goal", "asap in goal and q > 0"),
             "p =", 0,
             edit("dt = 0.1", "dt = 0.1\n  let p = x + 1\n  let q = p * x", "asap in goal", "asap in goal and q > 0")),
    "E121": (edit("dt = 0.1", "dt = 0.1\n  const c = x + 1", "ball([1, 0], 0.5)", "ball([c, 0], 0.5)"), "x + 1", 0,
             edit("dt = 0.1", "dt = 0.1\n  const c = pi / 4", "ball([1, 0], 0.5)", "ball([c, 0], 0.5)")),
    "E122": (edit("state x in [-5, 5]", "state x in [-inf, inf]"), "state x", 0,
             edit("state x in [-5, 5]", "state x in [-inf, inf] init [-5, 5]")),
    "E123": (edit("ball([-1, 0], 0.2)", "box(y in [-5, 5])"), "avoid in unsafe", 0,
             edit("ball([-1, 0], 0.2)", "box(y in [-5, 0])")),
    "E124": (edit("y' = u", "y' = u + sqrt(x - 10)"), "sqrt(x - 10)", 0,
             edit("y' = u", "y' = u + sqrt(x + 10)")),
    "W209": (edit("asap in goal", "asap in goal and log(y) < 1"), "log(y)", 0,
             edit("asap in goal", "asap in goal and log(y + 6) < 1")),
    "E125": (edit("asap in goal", "asap in goal and in unsafe"), "asap in goal", 0,
             edit("asap in goal", "asap in goal and not in unsafe")),
    "W201": (edit("ball([-1, 0], 0.2)", "ball([1.5, 0], 0.2)"), "avoid in unsafe", 0,
             edit("ball([-1, 0], 0.2)", "ball([1.75, 0], 0.2)")),
    "W202": (edit("dt = 0.1", "dt = 0.1\n  const k = 2"), "k =", 0,
             edit("dt = 0.1", "dt = 0.1\n  const k = 2", "y' = u", "y' = k * u")),
    "W203": (edit("asap in goal", "asap historically[0, 40] in goal"), "asap historically", 0,
             edit("asap in goal", "asap historically[0, 30] in goal")),
    "W204": (edit("deadline 30", "deadline 30\n  r_sat 10"), "r_sat", 0,
             edit("deadline 30", "deadline 30\n  r_sat 1000")),
    "W206": (edit("ball([1, 0], 0.5)", "ball([4.8, 0], 0.5)"), "asap in goal", 0,
             edit("ball([1, 0], 0.5)", "ball([4.5, 0], 0.5)")),
    "W207": (edit("state x in [-5, 5]", "state x in [-inf, inf] init [-5, 5]"), "asap in goal", 0,
             edit("state x in [-5, 5]", "state x in [-inf, inf] init [-5, 5]", "deadline 30", "deadline 30\n  r_sat 5")),
}


def test_every_rule_has_a_case():
    assert set(RULES) - NOT_HERE == set(CASES)


def test_rule_codes_are_stable_and_well_formed():
    for code, rule in RULES.items():
        assert rule.code == code
        assert re.fullmatch(r"[EW]\d{3}", code)
        assert rule.severity == ("error" if code[0] == "E" else "warning")
        assert re.fullmatch(r"[a-z]+(-[a-z]+)*", rule.name)
    names = [r.name for r in RULES.values()]
    assert len(names) == len(set(names))
    # the lint rules use registered codes
    assert {cls.code for cls in LINT_RULES} <= set(RULES)


@pytest.mark.parametrize("code", sorted(CASES))
def test_rule_fires_at_position(code):
    src, needle, nth, _ = CASES[code]
    found = [d for d in diagnostics(src) if d.code == code]
    assert found, f"{code} did not fire: {[d.code for d in diagnostics(src)]}"
    line, col = position(src, needle, nth)
    assert (found[0].line, found[0].column) == (line, col), found[0]
    d = found[0]
    assert d.severity == RULES[code].severity
    assert d.end_line > d.line or (d.end_line == d.line and d.end_column > d.column)
    assert d.message and "__" not in d.message


@pytest.mark.parametrize("code", sorted(CASES))
def test_rule_quiet_on_close_variant(code):
    src = CASES[code][3]
    found = codes(src)
    assert code not in found
    assert not [c for c in found if c.startswith("E")], found
    asap_dsl.loads(src)  # a valid program


def test_base_is_clean():
    prog = asap_dsl.loads(BASE)
    assert prog.warnings == []


def test_errors_make_loads_raise_warnings_do_not():
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(CASES["E101"][0])
    assert [d.code for d in info.value.errors] == ["E101"]
    prog = asap_dsl.loads(CASES["W201"][0])
    assert [w.code for w in prog.warnings] == ["W201"]


# More ways to fire the rules that have several triggers.
MORE = [
    ("E102", edit("dt = 0.1", "dt = 0.1\n  const pi = 3"), "pi = 3"),
    ("E102", edit("region unsafe", "region goal"), "goal = ball([-1"),
    ("E103", edit("asap in goal", "asap in goal and u > 0"), "u > 0"),
    ("E104", edit("y' = u", "y' = atan2(x) + u"), "atan2(x)"),
    ("E105", edit("state y in [-5, 5]", "state y in [5, -5]"), "[5, -5]"),
    ("E105", edit("deadline 30", "deadline 30\n  episode 20..10"), "episode"),
    ("E106", edit("deadline 30", "deadline 2.5"), "2.5"),
    ("E110", edit("y' = u", "y' = u\n    u' = x"), "u' = x"),
    ("E112", edit("deadline 30", "deadline 30\n  episode 10..40"), "episode"),
    ("E114", "system Empty { state x in [0, 1] }", "Empty"),
    ("E114", "region goal = ball([1], 0.5)", None),
    ("E114", "system Drift {\n  state x in [0, 1]\n  dt = 0.1\n  ode { x' = -x }\n}\nregion g = ball([0.5], 0.1)\n"
             "task t {\n  asap in g\n  deadline 5\n}\n", "system Drift"),
    ("E116", edit("y' = u", "y' = u + in goal"), "in goal"),
    ("E117", edit("ball([1, 0], 0.5)", "ball([1, 0], -0.5)"), "-0.5"),
    ("E117", edit("deadline 30", "deadline 30\n  reward rhoo"), "reward"),
    ("E117", edit("deadline 30", "deadline 30\n  train { algo = sacc }"), "algo"),
    ("E117", edit("deadline 30", "deadline 30\n  observe time"), "time"),
    ("E119", edit("dt = 0.1", "dt = 0.1\n  integrator euler", "ode {\n    x' = y\n    y' = u\n  }", "map {\n    x = y\n    y = u\n  }"), "integrator"),
    ("E119", edit("deadline 30", "deadline 30\n  deadline 20"), "deadline 20"),
    ("E120", edit("region unsafe", "formula f = f and in goal\nregion unsafe"), "f = f"),
    ("E121", edit("state y in [-5, 5]", "state y in [-5, x]"), "x]"),
    ("E122", edit("state x in [-5, 5]", "state x in [-1e308, 1e308] init [-1e308, 1e308]"), "[-1e308, 1e308]\n"),
    ("W201", edit("ball([-1, 0], 0.2)", "box(x in [0.8, 1.2])"), "avoid in unsafe"),  # y is free in the box
    ("W201", edit("ball([1, 0], 0.5)", "box(y in [-1, 1])", "ball([-1, 0], 0.2)", "box(x in [-1, 1])"), "avoid in unsafe"),
]


@pytest.mark.parametrize("code, src, needle", MORE)
def test_more_triggers(code, src, needle):
    found = [d for d in diagnostics(src) if d.code == code]
    assert found, [(d.code, d.message) for d in diagnostics(src)]
    if needle is not None:
        assert any((d.line, d.column) == position(src, needle) for d in found), found


def test_docs_list_every_rule():
    text = DOCS.read_text(encoding="utf-8")
    for code, rule in RULES.items():
        row = re.search(rf"^\|\s*`?{code}`?\s*\|\s*`?{rule.name}`?\s*\|\s*{rule.severity}\s*\|", text, re.M)
        assert row, f"{code} {rule.name} is not in the rule table of docs/language.md"


def test_extreme_centres_give_diagnostics_not_numpy_warnings():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = codes(edit("ball([1, 0], 0.5)", "ball([1e308, 0], 0.5)"))
    assert "E113" in got  # the goal lies far outside the state space


def test_w201_stays_quiet_for_a_box_obstacle_beside_a_ball_goal():
    assert "W201" not in codes(edit("ball([-1, 0], 0.2)", "box(x in [1.6, 2])"))


def test_w201_judges_the_target_of_a_conjunction_not_each_region():
    """`asap in goal and in slow`: `slow`, a box over y only, meets the unsafe box, but the target
    is its intersection with the goal, which does not; an `or` branch without the goal still warns."""
    src = edit("region unsafe = ball([-1, 0], 0.2)", "region unsafe = box(x in [-2, -1])\nregion slow = box(y in [-0.1, 0.1])")
    assert "W201" not in codes(src.replace("asap in goal", "asap in goal and in slow"))
    assert "W201" not in codes(src.replace("asap in goal", "asap in slow and x > 0 and in goal"))
    assert "W201" in codes(src.replace("asap in goal", "asap (in goal and in slow) or in slow"))
    assert "W201" in codes(src.replace("asap in goal", "asap in slow"))


def test_regions_overlap_judges_only_regions_asap_asks_to_be_in():
    # `not in unsafe` asks to be out of it: no overlap warning, however close the regions are
    # (goal and unsafe are apart in BASE: only an asap that asks to be in `unsafe` overlaps it)
    assert "W201" not in codes(BASE.replace("asap in goal", "asap in goal and (not in unsafe) since in goal"))
    assert "W201" not in codes(BASE.replace("asap in goal", "asap in goal and (in unsafe -> x > 9)"))
    # through a formula, and on the right of ->, it is positive
    assert "W201" in codes(BASE.replace("task t {", "formula bad = in unsafe\ntask t {").replace(
        "asap in goal", "asap in goal or (x > 0 -> bad)"))


def test_an_asap_that_can_never_hold_is_an_error_and_an_or_needs_every_branch_impossible():
    assert "E125" in codes(BASE.replace("asap in goal", "asap in goal and in unsafe"))
    assert "E125" in codes(BASE.replace("asap in goal", "asap (in goal and in unsafe) or (in unsafe and in goal)"))
    assert "E125" not in codes(BASE.replace("asap in goal", "asap (in goal and in unsafe) or in goal"))
    assert "E125" not in codes(BASE.replace("asap in goal", "asap once[0, 3] in goal and in unsafe"))


def test_w208_after_a_search_that_ran_out_of_time_names_deep_seconds():
    """The mountain car's oracle needs seconds per state: in 1 s for the task the search decides
    nothing, and the hint is more time (issue 20), not a larger deadline."""
    from asap_dsl.lint import deadline_checks

    prog = asap_dsl.load(DOCS.parents[1] / "examples" / "mountain_car.asap")
    warnings, skipped = deadline_checks(prog, samples=2, seconds=1.0)
    assert not skipped and [w.code for w in warnings] == ["W208"]
    w = warnings[0]
    assert "were not shown to fulfil" in w.message and "no way found in" in w.message
    assert "--deep-seconds 60" in w.hint and "enlarge the deadline" not in w.hint
