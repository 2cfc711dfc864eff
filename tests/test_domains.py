"""Numbers that leave their domain: lint finds them (E124 surely, W209 maybe), interval bounds
stay sound where they do, and at run time a NaN or an overflowing reward ends the episode as
``non_finite`` with finite rewards, observations and info."""

from __future__ import annotations

import math

import numpy as np
import pytest

import asap_dsl
from asap_dsl import intervals
from asap_dsl.env import make_env, make_vec_env
from asap_dsl.intervals import Interval
from asap_dsl.rewards import parse_reward
from conftest import BASE, codes, diagnostics

# x, y in [-5, 5]; u in [-1, 1]
CONDITION = [
    ("sqrt(x - 10) < 1", "E124"), ("sqrt(x) < 1", "W209"), ("sqrt(x + 10) < 1", None),
    ("log(x - 6) < 1", "E124"), ("log(y) < 1", "W209"), ("log(y + 6) < 1", None),
    ("asin(x + 7) < 1", "E124"), ("asin(x) < 1", "W209"), ("asin(x / 10) < 1", None),
    ("acos(x) < 1", "W209"), ("acos(x / 5) < 1", None),
    ("1 / (x - 10) < 1", None), ("1 / x < 1", "W209"), ("1 / (x - x) < 1", "W209"),
    ("(x - 6) ^ 0.5 < 1", "E124"), ("x ^ 0.5 < 1", "W209"), ("(x + 6) ^ 0.5 < 1", None),
    ("x ^ 2 < 1", None), ("x ^ -1 < 1", "W209"), ("(x + 6) ^ -1 < 1", None), ("x ^ y < 1", "W209"),
    ("x + (inf - inf) < 1", "E124"),
    ("exp(1000 * x) < 1", "W209"), ("exp(x) < 1", None), ("x * 1e308 < 1", "W209"), ("10 ^ (100 * y) < 1", "W209"),
    ("sqrt(sqrt(x)) < 1", "W209"),  # reported once, at the innermost
]


def spec_with(condition: str) -> str:
    return BASE.replace("asap in goal", f"asap in goal and {condition}")


@pytest.mark.parametrize("condition, code", CONDITION)
def test_domain_of_every_operation(condition, code):
    found = [c for c in codes(spec_with(condition)) if c in ("E124", "W209")]
    assert found == ([code] if code else []), condition


def test_dynamics_are_checked_with_the_action_bounds():
    assert "W209" in codes(BASE.replace("y' = u", "y' = 1 / u"))
    assert "E124" in codes(BASE.replace("y' = u", "y' = sqrt(u - 2)"))
    assert "E124" not in codes(BASE.replace("y' = u", "y' = sqrt(u + 2)"))


@pytest.mark.parametrize("term", ["10^400", "2^2^2^2^2^2", "exp(1000)", "1e308 * 10"])
def test_a_constant_term_that_overflows_is_an_error_not_a_crash(term):
    """Found by the hostile review: `2^2^...^2` in the dynamics was lint-clean, and the oracle then
    stopped on Python's OverflowError (exit 70). Finite numbers in, an infinity out: E124 there."""
    (d,) = [d for d in diagnostics(BASE.replace("y' = u", f"y' = u + {term}")) if d.code in ("E124", "W209")]
    assert d.code == "E124" and "overflows" in d.message
    assert "E124" not in codes(BASE.replace("y' = u", "y' = u + 2^2^2"))


def test_a_let_is_reported_once_at_its_definition():
    src = BASE.replace("dt = 0.1", "dt = 0.1\n  let q = sqrt(x)").replace(
        "asap in goal", "asap in goal and q < 1 and q > -1").replace("y' = u", "y' = u + q")
    found = [d for d in diagnostics(src) if d.code == "W209"]
    assert len(found) == 1
    assert "let 'q'" in found[0].message and found[0].line == 6


def test_enclosures_are_sound_where_the_domain_is_left():
    # NaN for part of the argument: nothing narrower than the line encloses it
    unknown = Interval(-math.inf, math.inf)
    assert intervals.sqrt(Interval(-15, -5)) == unknown
    assert intervals.sqrt(Interval(-1, 4)) == unknown
    assert intervals.log(Interval(-1, 4)) == unknown
    assert intervals.asin(Interval(-2, 0.5)) == unknown
    assert Interval(-2, 3) ** 0.5 == unknown
    assert intervals.sqrt(Interval(1, 4)) == Interval(1, 2)  # exact inside the domain
    prog = asap_dsl.loads(spec_with("sqrt(x) < 1"))
    lo, hi = prog.task("t").rho_bounds
    assert lo == -math.inf  # sqrt(x) of a negative x is NaN: the bound is not [0, 1]


@pytest.mark.parametrize("condition", ["sqrt(x + 5) > 1", "log(y + 5.5) < 0.2", "asin(x / 6) * y > 0",
                                       "(x + 5) ^ 1.5 - y < 3", "x / (y + 6) > 0", "acos(y / 5) + x > 1"])
def test_bounds_contain_every_sampled_value(condition):
    prog = asap_dsl.loads(spec_with(condition))
    atom = prog.task("t").asap.ir.right
    lo, hi = atom.bounds
    states = np.random.default_rng(0).uniform(-5, 5, size=(20000, 2))
    values = atom.robustness(states)
    assert np.isfinite(values).all()
    assert lo <= values.min() and values.max() <= hi, (lo, hi, values.min(), values.max())


NAN_SPEC = """\
system s {
  state x in [-5, 5]
  action u in [-1, 1]
  dt = 0.1
  ode { x' = u }
}
task t {
  asap sqrt(x) < 0.5
  deadline 10
}
"""


def _all_finite(value) -> bool:
    if isinstance(value, dict):
        return all(_all_finite(v) for v in value.values())
    if isinstance(value, (float, np.ndarray)):
        return bool(np.isfinite(value).all())
    return True


def test_a_nan_robustness_ends_the_episode_as_non_finite():
    prog = asap_dsl.loads(NAN_SPEC)
    env = make_vec_env(prog, num_envs=16, seed=0)
    env.reset()
    reasons = []
    with np.errstate(all="raise"):  # no numpy warning reaches the user either
        for _ in range(12):
            obs, rewards, dones, infos = env.step(np.zeros((16, 1)))
            assert np.isfinite(obs).all() and np.isfinite(rewards).all()
            assert all(_all_finite(i) for i in infos)
            reasons += [i["end_reason"] for i in infos if i["end_reason"]]
            for i, info in enumerate(infos):
                if info["end_reason"] == "non_finite":
                    assert dones[i] and rewards[i] == 0.0 and not info["satisfied"]
    assert "non_finite" in reasons


def test_the_failure_reward_is_the_value_of_a_non_finite_step():
    prog = asap_dsl.loads(NAN_SPEC.replace("[-5, 5]", "[-5, 5] init [-5, -1]"))  # sqrt(x) is NaN at once
    env = make_env(prog, seed=3, failure_reward=-7.0)
    _, info = env.reset()
    assert info["rho"] == 0.0 and not info["satisfied"]
    _, r, terminated, truncated, info = env.step(np.zeros(1))
    assert (r, terminated, truncated, info["end_reason"]) == (-7.0, True, False, "non_finite")


def test_a_reward_beyond_float32_ends_the_episode():
    src = """\
system s {
  state x in [-1e300, 1e300] init [-1, 1]
  action u in [-1, 1]
  dt = 1
  map { x = x + 1e299 * (u + 2) }
}
region goal = ball([0], 0.5)
task t {
  asap in goal
  deadline 10
  reward distance(lambda_t = 1)
}
"""
    env = make_vec_env(asap_dsl.loads(src), num_envs=4, seed=0)
    env.reset()
    obs, rewards, dones, infos = env.step(np.ones((4, 1)))
    assert np.isfinite(rewards).all() and np.isfinite(obs).all()
    assert all(i["end_reason"] == "non_finite" for i in infos) and dones.all()


@pytest.mark.parametrize("clause", ["r_sat 1e39", "r_sat inf", "reward distance(lambda_t = 1e39)",
                                    "reward distance(base = -inf)"])
def test_reward_numbers_must_fit_a_float32(clause):
    found = diagnostics(BASE.replace("deadline 30", f"deadline 30\n  {clause}"))
    assert any(d.code == "E117" and "3.4e38" in d.message for d in found), found


def test_reward_settings_and_failure_reward_outside_float32_are_refused():
    with pytest.raises(ValueError, match="3.4e38"):
        parse_reward("distance(lambda_t = 1e39)")
    with pytest.raises(ValueError, match="3.4e38"):
        make_env(asap_dsl.loads(BASE), failure_reward=-1e39)


@pytest.mark.parametrize("bounds", ["[-1e39, 1]", "[0, 1e39]", "[-1e300, 1e300]"])
def test_action_bounds_beyond_float32_are_an_error_not_an_overflow(bounds):
    """Found by the fuzz: `action u in [-1e39, 1e39]` is finite, but its float32 action space
    was ±inf (numpy warned "overflow encountered in cast") and drawing actions from it raised
    OverflowError. An agent's actions are float32: such bounds are one E117."""
    src = BASE.replace("action u in [-1, 1]", f"action u in {bounds}")
    found = [d for d in diagnostics(src) if d.code == "E117"]
    assert len(found) == 1 and "float32" in found[0].message and "action 'u'" in found[0].message, found
    edge = BASE.replace("action u in [-1, 1]", "action u in [-3.4e38, 3.4e38]")  # float32 holds these
    env = make_vec_env(asap_dsl.loads(edge), num_envs=2, seed=0)
    assert np.isfinite(env.action_space.low).all() and np.isfinite(env.action_space.high).all()


def test_an_exact_step_that_overflows_is_an_error_and_the_oracle_says_nan_not_infeasible():
    """Found by the hostile review: stiff linear dynamics over a long dt under `integrator exact`
    were lint-clean, and the oracle called every state "infeasible" (its NaN step)."""
    stiff = BASE.replace("dt = 0.1", "dt = 1000\n  integrator exact").replace("y' = u", "y' = 1e6 * y + u")
    (d,) = [d for d in diagnostics(stiff) if d.code == "E124"]
    assert "overflows a float" in d.message
    assert "E124" not in codes(stiff.replace("dt = 1000", "dt = 1e-7"))
