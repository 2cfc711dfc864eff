"""The checker: every error of a file at once and sorted, "did you mean" suggestions, the
formatted report, and the meaning of what checks (constants, lets, regions, tasks)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import asap_dsl
from asap_dsl.diagnostics import format_diagnostic
from conftest import BASE, diagnostics, position
from test_parser import lark_internal


def edit(src: str, *pairs: str) -> str:
    for old, new in zip(pairs[::2], pairs[1::2]):
        assert old in src, old
        src = src.replace(old, new, 1)
    return src


MANY = """\
system Plant {
  const k = 2, m = q + 1
  state x in [-5, 5] init [-6, 0]
  state y in [-5, 5]
  action u in [-1, 1]
  dt = 0.1
  ode {
    x' = y * kk
    y' = sni(u)
  }
}
region goal = ball([1, 0, 0], 0.5)
region unsafe = ball([-1, 0], 0.2)
formula near = x == 1
task t {
  asap eventually in goal
  avoid in unsafee
  deadline 2.5
}
"""


def test_all_errors_at_once_sorted_by_position():
    diags = diagnostics(MANY)
    errors = [d for d in diags if d.severity == "error"]
    got = [(d.code, d.line, d.column) for d in errors]
    assert ("E101", 2, 20) in got        # q
    assert ("E101", 8, 14) in got        # kk -> k
    assert ("E118", 9, 10) in got        # sni -> sin
    assert ("E104", 12, 20) in got       # centre [1, 0, 0]
    assert ("E115", 14, 18) in got       # ==
    assert ("E107", 16, 8) in got        # eventually in asap
    assert ("E101", 17, 12) in got       # unsafee -> unsafe
    assert ("E106", 18, 12) in got       # deadline 2.5
    keys = [(d.line, d.column) for d in diags]
    assert keys == sorted(keys)
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(MANY)
    assert [(d.code, d.line, d.column) for d in info.value.errors] == got


@pytest.mark.parametrize("src, wrong, right", [
    (edit(BASE, "x' = y", "x' = yy"), "yy", "y"),                                  # state
    (edit(BASE, "asap in goal", "asap in gool"), "gool", "goal"),                 # region
    (edit(BASE + "formula reached = in goal\n", "asap in goal", "asap reachd"), "reachd", "reached"),   # formula
    (edit(BASE, "y' = u", "y' = sqr(u)"), "sqr", "sqrt"),                          # function
    (edit(BASE, "dt = 0.1", "dt = 0.1\n  integrator rk5"), "rk5", "rk4"),          # integrator
    (edit(BASE, "dt = 0.1", "dt = 0.1\n  integrator eular"), "eular", "euler"),
    (edit(BASE, "deadline 30", "deadline 30\n  train { algo = sak }"), "algo = sak", "sac"),  # algo
    (edit(BASE, "deadline 30", "deadline 30\n  train { algo = ppo, stepz = 10 }"), "stepz", "steps"),  # setting
    (edit(BASE, "deadline 30", "deadline 30\n  reward distanse"), "reward distanse", "distance"),
    (edit(BASE, "deadline 30", "deadline 30\n  observe state, tim"), "tim", "time"),
    (edit(BASE, "dt = 0.1", "dt = 0.1\n  const gain = 2\n  let z = gian * x", "asap in goal", "asap in goal and z > 0"),
     "gian", "gain"),                                                               # constant
    (edit(BASE, "ode {\n    x' = y\n    y' = u\n  }", "ode {\n    x' = y\n    yy' = u\n  }"), "yy'", "y"),  # ode target
])
def test_did_you_mean(src, wrong, right):
    diags = [d for d in diagnostics(src) if d.severity == "error" and d.hint and "did you mean" in d.hint]
    assert len(diags) == 1, diagnostics(src)
    d = diags[0]
    assert (d.line, d.column) == position(src, wrong)
    assert d.hint == f"did you mean '{right}'?"
    assert not lark_internal(d.message)


def test_no_suggestion_for_far_names():
    src = edit(BASE, "asap in goal", "asap in zzzzzz")
    [d] = [d for d in diagnostics(src) if d.code == "E101"]
    assert d.hint is None and d.message == "unknown region 'zzzzzz'"


def test_formatted_report_shape():
    src = edit(BASE, "asap in goal", "asap in gaol")
    d = [d for d in diagnostics(src, "spec.asap") if d.code == "E101"][0]
    text = format_diagnostic(d, src).splitlines()
    assert text[0] == "spec.asap:14:11: error E101 unknown-name: unknown region 'gaol'"
    assert text[1] == "    14 |   asap in gaol"
    assert text[2] == "       |           ^^^^"
    assert text[3] == "       = hint: did you mean 'goal'?"
    # the caret sits under the span
    assert text[2].index("^") == text[1].index("gaol")


def test_report_with_tabs_and_multiline_span():
    src = edit(BASE, "  asap in goal", "\tasap in gaol")
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(src)
    lines = str(info.value).splitlines()
    i = next(k for k, line in enumerate(lines) if "E101" in line)
    assert lines[i + 2].index("^") == lines[i + 1].index("gaol")


def test_messages_are_plain_words_across_rules():
    srcs = [MANY, edit(BASE, "[-5, 5]", "[-5 5]"), "system", "task t {", "region r = ball(", "}",
            edit(BASE, "deadline 30", "deadline"), edit(BASE, "ball([1, 0], 0.5)", "ball([1, 0] 0.5)")]
    for src in srcs:
        for d in diagnostics(src):
            assert not lark_internal(d.message), d.message
            assert "__ANON" not in (d.hint or "") and "$END" not in (d.hint or ""), d.hint


# ---------------------------------------------------------------- meaning

def test_constants_use_earlier_constants_only():
    prog = asap_dsl.loads(edit(BASE, "dt = 0.1", "const a = 2, b = a * pi\n  dt = b / (20 * pi)",
                               "y' = u", "y' = a * u"))
    assert prog.system.consts["b"] == pytest.approx(2 * math.pi)
    assert prog.system.dt == pytest.approx(0.1)
    src = edit(BASE, "dt = 0.1", "const b = a * 2, a = 1\n  dt = 0.1", "y' = u", "y' = a * b * u")
    [d] = [d for d in diagnostics(src) if d.code == "E101"]
    assert "before it is declared" in d.message and (d.line, d.column) == position(src, "a * 2")


def test_lets_in_formulas_and_regions():
    src = edit(BASE, "dt = 0.1", "let r2 = x^2 + y^2\n  let r = sqrt(r2)\n  dt = 0.1",
               "region unsafe = ball([-1, 0], 0.2)", "region unsafe = box(r in [0, 0.5])",
               "asap in goal", "asap in goal and r < 4")
    prog = asap_dsl.loads(src)
    states = np.array([[0.3, 0.4], [3.0, 4.0]])
    np.testing.assert_allclose(prog.regions["unsafe"].robustness(states), [0.0, -4.5])
    np.testing.assert_array_equal(prog.regions["unsafe"].satisfied(states), [True, False])


def test_named_ball_and_box():
    src = edit(BASE, "ball([1, 0], 0.5)", "ball({y: 1}, 0.5)", "ball([-1, 0], 0.2)", "box(x in [0, 2], y in [-1, 1])")
    prog = asap_dsl.loads(src)
    goal, unsafe = prog.regions["goal"], prog.regions["unsafe"]
    assert goal.coords == ("y",) and goal.centre == (1.0,)
    s = np.array([[100.0, 1.0], [1.0, 0.0], [3.0, 0.0]])
    np.testing.assert_allclose(goal.robustness(s), [0.5, -0.5, -0.5])
    np.testing.assert_allclose(unsafe.robustness(s), [-98.0, 1.0, -1.0])
    # regions over different variables: overlap is not judged (no W201)
    assert prog.warnings == []


def test_task_spec_and_bounds():
    prog = asap_dsl.loads(BASE)
    t = prog.task("t")
    assert t.deadline == 30 and t.tolerances == (30,) and t.episode == (30, 30)
    # rho of `in goal` over [-5, 5]^2: r - dist in [0.5 - |(-5,-5)-(1,0)|, 0.5]
    lo, hi = t.asap.bounds
    assert hi == pytest.approx(0.5)
    assert lo == pytest.approx(0.5 - math.hypot(6, 5))
    # r_sat auto = rho_max' + k_max + 1 with rho scaled by 1 / (rho_max - rho_min)
    assert t.r_sat_value == pytest.approx(0.5 / (hi - lo) + 30 + 1)


def test_task_clause_given_twice_and_unknown_names():
    src = edit(BASE, "deadline 30", "deadline 30\n  asap in unsafe")
    d = [d for d in diagnostics(src) if d.code == "E119"]
    assert d and "twice" in d[0].message


def test_future_operator_in_causal_formula_ref():
    src = BASE + "formula later = eventually[0, 3] in goal\n"
    src = edit(src, "asap in goal", "asap later")
    [d] = [d for d in diagnostics(src) if d.code == "E107"]
    assert (d.line, d.column) == position(src, "later\n")
    assert "past" in d.hint


def test_past_operators_allowed_in_asap_and_avoid():
    src = edit(BASE, "asap in goal", "asap historically[0, 5] in goal", "avoid in unsafe", "avoid once[0, 2] in unsafe since x > 0")
    t = asap_dsl.loads(src).task("t")
    assert t.asap.causal and t.avoid.causal


def test_map_and_simulator_systems():
    src = edit(BASE, "ode {\n    x' = y\n    y' = u\n  }", "map {\n    x = x + 0.1 * y\n    y = y + 0.1 * u\n  }")
    sys_ = asap_dsl.loads(src).system
    assert sys_.kind == "map"
    out = sys_.rhs(np.array([[1.0, 2.0]]), np.array([[3.0]]))
    np.testing.assert_allclose(out, [[1.2, 2.3]])


def test_integrator_settings():
    prog = asap_dsl.loads(edit(BASE, "dt = 0.1", "dt = 0.1\n  integrator euler(substeps = 10)"))
    assert (prog.system.integrator.method, prog.system.integrator.substeps) == ("euler", 10)
    assert asap_dsl.loads(BASE).system.integrator.method == "rk4"
    assert asap_dsl.loads(BASE).system.integrator.substeps == 4
    bad = edit(BASE, "dt = 0.1", "dt = 0.1\n  integrator rk4(substeps = 0.5)")
    assert "E117" in [d.code for d in diagnostics(bad)]


def test_distance_reward_needs_a_region_in_asap():
    base = "system A { state x in [-1, 1]  action u in [-1, 1]  dt = 1  map { x = x + u } }\nregion g = ball([0], 0.5)\n"
    asap_dsl.loads(base + "task t { asap in g and x > 0  deadline 3  reward distance(lambda_t = 2) }")
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(base + "task t { asap x > 0.5  deadline 3  reward distance }")
    (d,) = [d for d in info.value.diagnostics if d.code == "E117"]
    assert "names no region" in d.message and d.line == 3


@pytest.mark.parametrize(
    "text, code",
    [
        ("system A { const a = 1/0  state x in [0, 1]  dt = 0.1  map { x = x } }", "E117"),
        ("system A { state x in [0, 1]  dt = 0.1/0  map { x = x } }", "E117"),
        ("system A { state x in [0, 1]  dt = 10^400  map { x = x } }", "E117"),
        ("system A { state x in [0, 1]  dt = 1e-320  map { x = x } }\ntask t { asap x < 1  deadline 3s }", "E117"),
        ("system A { state x in [0, 1]  dt = 0.1  map { x = x } }\ntask t { asap x < 1  deadline 1e30 }", "E117"),
        ("system A { state x in [0, 1]  dt = 1e308  map { x = x } }\ntask t { asap x < 1  deadline 30 }", "E117"),
    ],
)
def test_degenerate_numbers_are_diagnostics_not_crashes(text, code):
    """Found by the fuzz: division by zero while folding constants, and times of 1e300 steps."""
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(text)
    assert code in [d.code for d in info.value.diagnostics]


@pytest.mark.parametrize("value", ["2^99999", "10^308 * 10", "exp(1000)", "-cosh(800)"])
def test_a_constant_that_overflows_says_so(value):
    """Not "not a real number": the value is a number too large for a float (10^308 * 10 was
    accepted as infinity before)."""
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(f"system A {{ const a = {value}  state x in [0, 1]  dt = 0.1  map {{ x = x }} }}")
    (d,) = [d for d in info.value.diagnostics if d.code == "E117"]
    assert "overflows" in d.message, d.message


def test_a_constant_may_be_infinite_where_inf_is_written():
    asap_dsl.loads("system A { const a = -inf  const b = 2 * a  state x in [b, 1] init [0, 1]  dt = 0.1  map { x = x } }")


def test_integrator_substeps_are_bounded():
    src = ("system A { state x in [0, 1]  action u in [-1, 1]  dt = 0.1  integrator rk4(substeps = 1e9)  ode { x' = u } }\n"
           "region g = ball([0.5], 0.1)\ntask t { asap in g  deadline 3 }")
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(src)
    (d,) = [d for d in info.value.diagnostics if d.code == "E117"]
    assert "more than 1,000" in d.message
    asap_dsl.loads(src.replace("1e9", "1000"))


def test_deadlines_are_bounded():
    src = ("system A { state x in [0, 1]  action u in [-1, 1]  dt = 0.1  ode { x' = u } }\n"
           "region g = ball([0.5], 0.1)\ntask t { asap once[0, 1000000000] in g  deadline 1000000000 }")
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(src)
    assert any(d.code == "E117" and "more than 1,000,000" in d.message for d in info.value.diagnostics)
    asap_dsl.loads(src.replace("deadline 1000000000", "deadline 1000000"))


@pytest.mark.parametrize("clause, where", [("r_sat inf", "inf"), ("reward distance(lambda_t = inf)", "inf"),
                                           ("reward distance(base = -inf)", "-inf")])
def test_infinite_reward_numbers_are_refused(clause, where):
    src = ("system A { state x in [0, 1]  action u in [-1, 1]  dt = 0.1  ode { x' = u } }\n"
           f"region g = ball([0.5], 0.1)\ntask t {{ asap in g  deadline 3  {clause} }}")
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(src)
    (d,) = [d for d in info.value.diagnostics if d.code == "E117"]
    assert "must be a finite number" in d.message


def test_infinite_reward_numbers_in_a_flag_are_refused():
    from asap_dsl.rewards import parse_reward

    with pytest.raises(ValueError, match="finite"):
        parse_reward("distance(lambda_t = inf)")


# ---------------------------------------------------------------- dt is a constant
def test_dt_is_read_in_expressions_like_a_constant():
    src = BASE.replace("dt = 0.1", "const T = 10\n  dt = T / 100\n  const h = dt / 2").replace(
        "  ode {\n    x' = y\n    y' = u\n  }", "  map {\n    x = x + dt * y\n    y = y + h * 2 * u\n  }").replace(
        "asap in goal", "asap in goal and x < dt * 40")
    prog = asap_dsl.loads(src)
    assert prog.system.dt == 0.1 and prog.system.consts["h"] == 0.05
    from asap_dsl.dynamics import numpy_step

    nxt = numpy_step(prog.system)(np.array([[1.0, 2.0]]), np.array([[1.0]]))
    assert np.allclose(nxt, [[1.0 + 0.1 * 2.0, 2.0 + 0.1]])
    assert not [d for d in prog.warnings if d.code == "W202"]  # dt is never "unused"


def test_dt_before_its_line_in_a_constant_is_said_in_words():
    src = BASE.replace("  state x", "  const a = dt\n  state x").replace("asap in goal", "asap in goal and x < a")
    found = [d for d in diagnostics(src) if d.is_error]
    assert [d.code for d in found] == ["E101"] and "'dt' is used before it is declared" in found[0].message


def test_a_reserved_word_read_as_a_value_gets_a_hint_that_says_so():
    src = BASE.replace("y' = u", "y' = u * task")
    (d,) = diagnostics(src)
    assert d.code == "E001" and "cannot name anything, nor be read as a value" in d.hint


# ---------------------------------------------------------------- region robustness bounds
def _region_spec(space, shape):
    return (f"system Plane {{\n  state x in [{space[0]}, {space[1]}]\n  state y in [{space[2]}, {space[3]}]\n"
            f"  action u in [-1, 1]\n  dt = 0.1\n  ode {{ x' = u, y' = u }}\n}}\nregion r = {shape}\n"
            f"task t {{ asap in r  deadline 10 }}\n")


@pytest.mark.parametrize("space, shape", [
    ((-3.15, 3.15, -8, 8), "box(x in [-0.15, 0.15], y in [-0.5, 0.5])"),   # the pendulum's upright box
    ((-5, 5, -5, 5), "box(x in [2, 9])"),                                  # partly outside the space
    ((-5, 5, -5, 5), "box(x in [4, 9], y in [0, 1])"),                     # the middle outside the space
    ((-5, 5, -5, 5), "ball([1, 0], 0.5)"), ((-5, 5, -5, 5), "ball({x: 5.5}, 1)"),
    ((0, 1, 0, 1), "ball([3, 3], 5)"),
])
def test_region_bounds_are_the_true_range_over_the_state_space(space, shape):
    prog = asap_dsl.loads(_region_spec(space, shape))
    lo, hi = prog.task("t").rho_bounds
    region = prog.regions["r"]
    rng = np.random.default_rng(0)
    grid = np.stack(np.meshgrid(np.linspace(space[0], space[1], 401), np.linspace(space[2], space[3], 401)), -1)
    states = np.concatenate([grid.reshape(-1, 2), rng.uniform(space[::2], space[1::2], size=(20000, 2))])
    rho = region.robustness(states)
    assert lo - 1e-12 <= rho.min() and rho.max() <= hi + 1e-12
    assert hi - rho.max() < 0.03 * max(1.0, hi - lo) and rho.min() - lo < 0.03 * max(1.0, hi - lo)  # tight
    if region.kind == "box":  # never above the smallest half-width; a ball's never above its radius
        assert hi <= min(b - a for a, b in zip(region.low, region.high)) / 2 + 1e-12
    else:
        assert hi <= region.radius + 1e-12


# ---------------------------------------------------------------- lets of actions, conditionals, maps without dt

ACTION_LET = """\
system Car {
  state p in [-2, 2] init [-1, 1]
  state v in [-1, 1]
  action u in [-1, 1]
  let push = clip(2 * u, -1, 1)
  let v_next = clip(v + 0.1 * push, -1, 1)
  map { p = clip(p + v_next, -2, 2), v = if p + v_next <= -2 and v_next < 0 then 0 else v_next }
}
region goal = box(p in [1, 2])
task t { asap in goal  deadline 50 }
"""


def test_a_let_may_read_actions_in_the_dynamics():
    prog = asap_dsl.loads(ACTION_LET)
    f = prog.system.rhs
    s = np.array([[0.0, 0.5], [-1.9, -0.5], [1.95, 0.9]])
    a = np.array([[0.3], [-1.0], [1.0]])
    want = []
    for (p, v), (u,) in zip(s, a):
        vn = min(max(v + 0.1 * min(max(2 * u, -1), 1), -1), 1)
        want.append([min(max(p + vn, -2), 2), 0.0 if p + vn <= -2 and vn < 0 else vn])
    np.testing.assert_array_equal(f(s, a), np.array(want))


def test_a_let_of_actions_is_evaluated_at_every_rk4_stage():
    base = ("system Osc {{ state x in [-5, 5]  action u in [-1, 1]  {let}  dt = 0.1  integrator rk4(substeps = 3)  "
            "ode {{ x' = {rhs} }} }}\nregion g = ball([1], 0.1)\ntask t {{ asap in g  deadline 5 }}")
    with_let = asap_dsl.loads(base.format(let="let f = u * x - sin(x)", rhs="f"))
    inline = asap_dsl.loads(base.format(let="", rhs="u * x - sin(x)"))
    from asap_dsl.dynamics import numpy_step

    s, a = np.array([[0.3], [-2.0]]), np.array([[0.7], [-0.2]])
    np.testing.assert_array_equal(numpy_step(with_let.system)(s, a), numpy_step(inline.system)(s, a))


@pytest.mark.parametrize("use, needle", [
    ("task t2 { asap push > 0  deadline 5 }", "push"),                               # a formula
    ("task t2 { asap in goal  avoid v_next < -0.5  deadline 5 }", "v_next"),          # avoid
    ("region r = box(push in [0, 1])\ntask t2 { asap in r  deadline 5 }", "push"),    # a region
    ("formula f = v + (if u > 0 then 1 else 0) > 0\ntask t2 { asap f  deadline 5 }", "u > 0"),  # an action itself
])
def test_a_let_of_actions_where_only_states_are_seen_is_an_error(use, needle):
    src = ACTION_LET + use + "\n"
    errors = [d for d in diagnostics(src) if d.severity == "error"]
    assert [d.code for d in errors] == ["E103"], errors
    d = errors[0]
    assert (d.line, d.column) == position(src, needle, src.count(needle) - 1)
    assert "action" in d.message


def test_a_let_of_actions_error_names_the_action():
    d = [d for d in diagnostics(ACTION_LET + "task t2 { asap v_next > 0  deadline 5 }\n") if d.severity == "error"][0]
    assert "let 'v_next': it reads the action 'u'" in d.message
    assert "ode/map equations" in d.hint


@pytest.mark.parametrize("test, message", [
    ("x", "a number cannot be the test of `if`"),
    ("in goal", "a region, a formula or a temporal operator"),
    ("once x > 0", "a region, a formula or a temporal operator"),
])
def test_the_test_of_if_compares_numbers(test, message):
    src = BASE.replace("y' = u", f"y' = if {test} then u else -u")
    errors = [d for d in diagnostics(src) if d.severity == "error"]
    assert [d.code for d in errors] == ["E116"] and message in errors[0].message
    line, col = position(src, f"if {test}")
    assert (errors[0].line, errors[0].column) == (line, col + 3)


def test_conditional_branches_are_numbers_and_functions_are_checked():
    assert "E116" in [d.code for d in diagnostics(BASE.replace("y' = u", "y' = if x > 0 then x < 1 else u"))]
    diags = diagnostics(BASE.replace("y' = u", "y' = clip(u, 1)"))
    assert [d.code for d in diags] == ["E104"] and "clip() takes 3 arguments, given 2" in diags[0].message


STEPS_MAP = """\
system Walk {
  state x in [-10, 10] init [0, 0]
  action u in [-1, 1]
  map { x = x + u }
}
region goal = box(x in [5, 10])
task t { asap in goal  deadline 20 steps }
"""


def test_a_map_needs_no_dt_and_counts_in_steps():
    prog = asap_dsl.loads(STEPS_MAP)
    assert prog.system.dt is None and prog.task("t").deadline == 20
    env = asap_dsl.make_vec_env(prog, "t", num_envs=2, seed=0)
    env.reset()
    env.step_arrays(np.ones((2, 1)))
    np.testing.assert_array_equal(env.core.states, [[1.0], [1.0]])


@pytest.mark.parametrize("edit_, needle", [
    (("deadline 20 steps", "deadline 2s"), "2s"),
    (("deadline 20 steps", "deadline 20  tolerances 500ms"), "500ms"),
    (("x = x + u", "x = x + u * dt"), "dt }"),
    (("task t {", "formula f = once[0, 1s] x > 0\ntask t {"), "1s"),
])
def test_seconds_in_a_map_without_dt_are_an_error(edit_, needle):
    src = edit(STEPS_MAP, *edit_)
    errors = [d for d in diagnostics(src) if d.severity == "error"]
    assert [d.code for d in errors] == ["E114"], errors
    assert "map without `dt`" in errors[0].message and "deadline 200" in errors[0].hint
    assert (errors[0].line, errors[0].column) == position(src, needle)


def test_an_ode_still_needs_dt():
    errors = [d for d in diagnostics(BASE.replace("  dt = 0.1\n", "")) if d.severity == "error"]
    assert [d.code for d in errors] == ["E114"] and "has no `dt = ...`" in errors[0].message


def test_map_right_hand_sides_read_the_old_state():
    swap = ("system Swap { state x in [-5, 5]  state y in [-5, 5]  action u in [-1, 1]\n"
            "  map { x = y, y = x + u } }\nregion g = ball([1, 1], 0.5)\ntask t { asap in g  deadline 5 }\n")
    prog = asap_dsl.loads(swap)
    np.testing.assert_array_equal(prog.system.rhs(np.array([[1.0, 2.0]]), np.array([[0.5]])), [[2.0, 1.5]])
    env = asap_dsl.make_vec_env(prog, "t", num_envs=1, seed=0)
    env.reset()
    env.core.states[:] = [[1.0, 2.0]]
    env.core.sim.reset(env.core.states.copy())
    env.step_arrays(np.array([[0.0]]))
    np.testing.assert_array_equal(env.core.states, [[2.0, 1.0]])


def test_show_of_a_map_without_dt_prints_steps_only(tmp_path, capsys):
    import json

    from conftest import asapc

    f = tmp_path / "walk.asap"
    f.write_text(STEPS_MAP)
    code, out, _ = asapc(capsys, "show", str(f))
    assert code == 0 and "no dt (times in steps)" in out and "deadline       20 steps\n" in out
    assert " s)" not in out and "dt =" not in out
    code, out, _ = asapc(capsys, "show", "--format", "json", str(f))
    data = json.loads(out)
    assert data["system"]["dt"] is None and data["tasks"]["t"]["deadline_seconds"] is None


def test_an_infinite_longest_episode_is_one_error():
    """Not also "the episode range 10..1 is reversed" (a default standing in for the bad bound)."""
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads("system A { state x in [0, 1]  action u in [-1, 1]  dt = 0.1  map { x = x + u } }\n"
                       "task t { asap x > 0.9  deadline 30  episode 10..inf }")
    assert [d.code for d in info.value.diagnostics] == ["E117"]
