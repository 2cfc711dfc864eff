"""Rewards equal the paper's definitions on hand-made traces."""

from pathlib import Path

import numpy as np
import pytest

import asap_dsl
from asap_dsl.rewards import make_reward, parse_reward, reward_trace
from asap_dsl.stl import ir, offline

SPECS = Path(__file__).resolve().parent.parent / "specs"
ALL = sorted(SPECS.glob("*.asap"))

LINE = """
system Line {
  state x in [-10, 10] init [-1, 1]
  state y in [-10, 10] init [-1, 1]
  action u in [-1, 1]
  dt = 1
  map { x = x + u
        y = y }
}
region goal   = ball([5, 0], 1)
region unsafe = box(x in [2, 3], y in [-1, 1])
task reach { asap in goal  deadline 10 }
task ra { asap in goal  avoid in unsafe  deadline 10 }
task fixed { asap in goal  deadline 10  r_sat 100 }
task cmp { asap x > 4  deadline 10 }
"""


@pytest.fixture(scope="module")
def line():
    return asap_dsl.loads(LINE, "line.asap")


TRACE = np.array([[0, 0], [1, 0], [2.5, 0.5], [4.5, 0], [5, 0], [6.5, 0], [5.5, 0]], dtype=float)


def test_asap_reward_auto_by_hand(line):
    t = line.task("reach")
    lo, hi = t.rho_bounds  # ball r - dist over [-10, 10]^2: [1 - sqrt(15^2 + 10^2), 1]
    assert hi == pytest.approx(1.0) and lo == pytest.approx(1 - np.hypot(15, 10))
    scale = 1 / (hi - lo)
    r_sat = hi * scale + 10 + 1
    rho = 1 - np.hypot(TRACE[:, 0] - 5, TRACE[:, 1])
    expect = np.where(rho >= 0, r_sat, rho * scale)[1:]
    assert np.allclose(reward_trace(line, "reach", TRACE), expect)
    # by hand: step 4 (x = 5) is in the goal; step 5 (x = 6.5) is out again: rho = -0.5
    assert reward_trace(line, "reach", TRACE)[4] == pytest.approx(-0.5 * scale)
    assert reward_trace(line, "reach", TRACE)[3] == pytest.approx(r_sat)


def test_asap_reward_numeric_r_sat_unscaled(line):
    r = reward_trace(line, "fixed", TRACE)
    rho = 1 - np.hypot(TRACE[1:, 0] - 5, TRACE[1:, 1])
    assert np.allclose(r, np.where(rho >= 0, 100.0, rho))


def test_rho_reward_is_prefix_spec_robustness(line):
    r = reward_trace(line, "ra", TRACE, reward="rho")
    spec = line.task("ra").spec
    expect = [spec.robustness(TRACE[: t + 1])[0] for t in range(1, len(TRACE))]
    assert np.allclose(r, expect)
    # by hand at step 2 (x = 2.5, inside the box by min(0.5, 0.5, 1.5, 0.5) = 0.5):
    # eventually part: max rho of goal so far = 1 - |(2.5, 0.5) - (5, 0)|; always-not-avoid: -0.5
    assert r[1] == pytest.approx(min(1 - np.hypot(2.5, 0.5), -0.5))


def test_window_reward_last_d_steps(line):
    r = reward_trace(line, "reach", TRACE, reward="rho(window = 2)")
    rho = 1 - np.hypot(TRACE[:, 0] - 5, TRACE[:, 1])
    expect = np.maximum(rho[1:], rho[:-1])  # once[0, 1] in goal
    assert np.allclose(r, expect)
    r3 = reward_trace(line, "ra", TRACE, reward="rho(window = 3)")
    t = line.task("ra").model
    node = ir.And(ir.Once(ir.Interval(0, 2), t.asap), ir.Historically(ir.Interval(0, 2), ir.Not(t.avoid)))
    assert np.allclose(r3, offline.robustness(node, TRACE)[1:])


def test_distance_reward_by_hand(line):
    r = reward_trace(line, "ra", TRACE, reward="distance(lambda_t = 2, lambda_o = 0.5, base = 3)")
    d_t = np.maximum(0, np.hypot(TRACE[:, 0] - 5, TRACE[:, 1]) - 1)
    gap_x = np.maximum(2 - TRACE[:, 0], 0) + np.maximum(TRACE[:, 0] - 3, 0)
    gap_y = np.maximum(-1 - TRACE[:, 1], 0) + np.maximum(TRACE[:, 1] - 1, 0)
    d_o = np.hypot(gap_x, gap_y)
    assert np.allclose(r, (-2 * d_t + 0.5 * d_o + 3)[1:])
    assert r[0] == pytest.approx(-2 * 3 + 0.5 * 1 + 3)  # x = 1: 3 from the goal, 1 from the box


def test_distance_needs_region_atoms(line):
    with pytest.raises(ValueError, match="distance reward needs region atoms"):
        asap_dsl.make_env(line, task="cmp", reward="distance")


@pytest.mark.parametrize("bad, message", [
    ("speed", "unknown reward 'speed'"),
    ("rhoo", "did you mean 'rho'"),
    ("rho(width = 3)", "has no setting 'width'"),
    ("rho(window = 0)", "at least one step"),
    ("distance(lambda_t = x)", "unknown constant 'x' in the reward 'distance\\(lambda_t = x\\)'"),
])
def test_bad_reward_names(line, bad, message):
    with pytest.raises(ValueError, match=message):
        asap_dsl.make_env(line, task="reach", reward=bad)


def test_unknown_task_is_a_key_error(line):
    with pytest.raises(KeyError, match="did you mean 'reach'"):
        asap_dsl.make_env(line, task="rech")


@pytest.mark.parametrize("path", ALL, ids=lambda p: p.stem)
def test_r_sat_auto_satisfies_theorem(path):
    prog = asap_dsl.load(path)
    for name in prog.tasks:
        t = prog.task(name).model
        assert t.r_sat is None
        lo, hi = t.rho_bounds
        s = t.rho_scale
        lo_, hi_ = lo * s, hi * s
        assert t.r_sat_value > hi_ + (hi_ - lo_) * t.k_max
        # and the env's per-step rewards before reaching never exceed rho_max'
        rw = make_reward(t, prog.regions, prog.system.n_state, 4)
        states = np.random.default_rng(0).uniform(prog.system.state_low, prog.system.state_high, (4, prog.system.n_state))
        v = rw.value(states, np.full(4, 1e9), np.zeros(4, bool))
        assert np.all(v <= hi_ + 1e-12)


def test_failure_step_earns_the_floor(line):
    env = asap_dsl.make_env(line, task="ra", seed=0)
    env.reset(seed=0)
    env.unwrapped.core.states[:] = [[1.5, 0.0]]
    env.unwrapped.core.sim.reset(env.unwrapped.core.states)
    obs, r, term, trunc, info = env.step([1.0])  # x = 2.5: inside the unsafe box
    t = line.task("ra").model
    assert term and info["end_reason"] == "avoid"
    assert r == pytest.approx(t.rho_bounds[0] * t.rho_scale)
    env2 = asap_dsl.make_env(line, task="ra", seed=0, failure_reward=-7.0)
    env2.reset(seed=0)
    env2.unwrapped.core.sim.reset(np.array([[1.5, 0.0]]))
    env2.unwrapped.core.states[:] = [[1.5, 0.0]]
    assert env2.step([1.0])[1] == -7.0


def test_parse_reward():
    assert parse_reward("rho(window = 5)").params == {"window": 5}
    assert parse_reward("distance").params == {"lambda_t": 1.0, "lambda_o": 1.0, "base": 0.0}


@pytest.mark.parametrize("text", ["rho(width = 3)", "rhoo", "distance(lambda_t = 1e39)", "rho(window = 2.5)",
                                  "rho(window = 0)", "asap(k = 1)"])
def test_a_reward_flag_is_checked_as_the_clause_is(text):
    """`--reward TEXT` is read by the grammar's own rule and checked by the checker's own code:
    its one sentence is the clause's diagnostic (message; hint)."""
    src = LINE.replace("task cmp { asap x > 4  deadline 10 }", f"task cmp {{ asap x > 4  deadline 10  reward {text} }}")
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(src)
    (d,) = info.value.errors
    with pytest.raises(ValueError) as flag:
        parse_reward(text)
    assert str(flag.value) == d.message + (f"; {d.hint}" if d.hint else "")


def test_a_reward_flag_takes_what_the_clause_takes():
    assert parse_reward("distance(lambda_t = 2 * pi, base = -1)").params == {"lambda_t": 2 * np.pi, "lambda_o": 1.0,
                                                                             "base": -1.0}
    assert parse_reward("rho( window=3 )").params == {"window": 3}
    assert parse_reward("rho(window = 500ms)", dt=0.1).params == {"window": 5}  # a time: needs the system's dt
    with pytest.raises(ValueError, match="no valid dt"):
        parse_reward("rho(window = 500ms)")
    env = asap_dsl.make_env(asap_dsl.loads(LINE.replace("dt = 1", "dt = 0.5")), task="reach", reward="rho(window = 2s)")
    assert env.unwrapped.core.reward.model.params == {"window": 4}


@pytest.mark.parametrize("text", ["rho(window = 5", "rho window", "", "distance(lambda_t = )", "rho(5)"])
def test_an_unreadable_reward_flag_is_one_sentence(text):
    with pytest.raises(ValueError) as info:
        parse_reward(text)
    message = str(info.value)
    assert message.startswith(f"cannot read the reward {text!r}: unexpected") and "\n" not in message
    assert "$END" not in message and "__ANON" not in message
