"""The batched rollout every controller goes through, and the statistics module."""

from __future__ import annotations

import numpy as np
import pytest

import asap_dsl
from asap_dsl.rollout import ConstantController, Evaluator, rollout
from asap_dsl.sampling import evaluation_states
from asap_dsl.stats import asap_gap, mean_spread, rate, steps_summary, wilson_interval
from conftest import RAIL

# The rail with a wider pit and a second task without it.
SPEC = RAIL.replace("[-2, -1.8]", "[-2, -1.6]") + """\
task right {
  asap in goal
  deadline 20
}
"""


@pytest.fixture(scope="module")
def prog():
    return asap_dsl.loads(SPEC, "rail.asap")


def test_constant_push_right_matches_the_closed_form(prog):
    states = np.array([[-1.0], [0.0], [0.79], [1.0], [1.5]])
    res = rollout(prog, "go", ConstantController([1.0]), states, record=True)
    # x moves 0.2 per step; the goal is [0.8, 1.2]: first step with x >= 0.8 (while x <= 1.2)
    expect = [9, 4, 1, 0, np.inf]  # 1.5 is beyond the goal and moves away, out of the space at 1.5 + 0.6
    assert res.t_reach.tolist() == expect
    assert res.end_reason.tolist()[-1] == "out_of_bounds" and res.end_step[-1] == 3
    assert res.end_reason.tolist()[:4] == ["out_of_bounds"] * 4  # pushing right forever leaves the rail
    # the recorded trajectory agrees with the offline semantics of `asap`
    tr = res.trajectories
    for i in range(len(states)):
        n = res.end_step[i] + 1
        first = prog.task("go").asap.first_time(tr[i, :n])
        assert first == res.t_reach[i]
        assert np.all(np.isnan(tr[i, n:]))


def test_failure_before_reaching_is_not_a_success(prog):
    states = np.array([[-1.2], [0.5]])
    res = rollout(prog, "go", ConstantController([-1.0]), states)
    assert res.end_reason.tolist() == ["avoid", "avoid"]
    assert not np.isfinite(res.t_reach).any()
    assert res.failures() == {"avoid": 2, "out_of_bounds": 0, "non_finite": 0, "not_reached": 0}


def test_success_is_monotone_in_the_tolerance_and_evaluator_is_reusable(prog):
    states = evaluation_states(prog.system, 200, seed=3, avoid=prog.task("go").model.avoid)
    ev = Evaluator(prog, "go", states)
    a = ev.run(ConstantController([1.0]))
    b = ev.run(ConstantController([1.0]))
    assert np.array_equal(a.t_reach, b.t_reach) and np.array_equal(a.returns, b.returns)
    assert a.rate(5) <= a.rate(10) <= a.rate(20)
    c = ev.run(ConstantController([0.0]))  # standing still reaches only from inside the goal
    assert c.rate(20) == np.mean(np.abs(states[:, 0] - 1.0) <= 0.2)


def test_controller_sees_obs_and_true_states_once_per_step(prog):
    calls = []

    class Spy:
        def reset(self, states):
            calls.append(("reset", states.shape))

        def act(self, obs, states, t):
            calls.append((t, obs.shape, obs.dtype, states.shape))
            return np.zeros((len(states), 1))

    rollout(prog, "right", Spy(), np.zeros((7, 1)))
    assert calls[0] == ("reset", (7, 1))
    assert [c[0] for c in calls[1:]] == list(range(20))
    assert all(c[1] == (7, 1) and c[2] == np.float32 and c[3] == (7, 1) for c in calls[1:])


def test_rollout_rejects_bad_states(prog):
    with pytest.raises(ValueError, match="1 states"):
        rollout(prog, "go", ConstantController([0.0]), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="non-empty"):
        rollout(prog, "go", ConstantController([0.0]), np.zeros((0, 1)))


def test_wilson_interval_known_values():
    lo, hi = wilson_interval(53, 100)
    assert lo == pytest.approx(0.4329, abs=1e-4) and hi == pytest.approx(0.6249, abs=1e-4)
    assert wilson_interval(0, 10)[0] == 0.0 and wilson_interval(10, 10)[1] == 1.0
    assert wilson_interval(0, 0) == (0.0, 1.0)
    r = rate(np.array([True, False, True, True]))
    assert r["count"] == 3 and r["states"] == 4 and r["rate"] == 0.75 and r["ci95"][0] < 0.75 < r["ci95"][1]
    assert rate(np.array([], bool))["rate"] is None


def test_asap_gap_is_the_median_ratio_over_states_both_reach():
    policy = np.array([10, 12, np.inf, 8, 5, 0])
    oracle = np.array([10, 10, 9, np.inf, 4, 0])  # inf: oracle did not reach; 0: nothing to gain
    g = asap_gap(policy, oracle)
    assert g["states"] == 3
    assert g["gap"] == pytest.approx(np.median([1.0, 1.2, 1.25]))
    assert g["share_optimal"] == pytest.approx(1 / 3)
    none = asap_gap(np.array([np.inf]), np.array([3.0]))
    assert none["gap"] is None and "no state" in none["reason"]


def test_steps_summary_and_mean_spread():
    s = steps_summary(np.array([1, 2, 3, 4, np.inf]))
    assert s["reached"] == 4 and s["median"] == 2.5 and s["max"] == 4
    assert steps_summary(np.array([np.inf]))["reached"] == 0
    m = mean_spread([0.5, 0.7, None])
    assert m["n"] == 2 and m["mean"] == pytest.approx(0.6) and m["std"] == pytest.approx(np.std([0.5, 0.7], ddof=1))


class _Noisy:
    """A state-feedback controller with seeded noise: the same actions whatever steps the core."""

    def __init__(self, m: int, low, high):
        self.m, self.low, self.high = m, np.asarray(low), np.asarray(high)

    def reset(self, states):
        self.rng = np.random.default_rng(3)

    def act(self, obs, states, t):
        gain = -np.tanh(states[:, : self.m])
        noise = self.rng.uniform(-0.5, 0.5, size=gain.shape)
        return self.low + (self.high - self.low) * (0.5 + 0.5 * np.clip(gain + noise, -1, 1))


@pytest.mark.parametrize("spec,task", [("dc_motor", "reach_avoid"), ("bicycle", "reach_avoid"),
                                       ("attitude", "reach_avoid"), ("attitude", "reach")])
def test_compiled_and_numpy_evaluators_judge_alike(spec, task):
    """The Evaluator steps with the compiled core where it covers the task; every number it
    reports (first reach, end reasons and steps, returns, trajectories, ρ) is the numpy core's."""
    from conftest import ROOT

    prog = asap_dsl.load(ROOT / "specs" / f"{spec}.asap")
    from asap_dsl.sampling import task_states

    states = task_states(prog.system, prog.task(task).model, 64)
    sysm = prog.system
    ctrl = _Noisy(sysm.n_action, sysm.action_low, sysm.action_high)
    native = Evaluator(prog, task, states, engine="native")
    numpy_ = Evaluator(prog, task, states, engine="numpy")
    assert native.core.engine == "native" and getattr(numpy_.core, "engine", "numpy") != "native"
    a = native.run(ctrl, record=True, robustness=True)
    b = numpy_.run(ctrl, record=True, robustness=True)
    assert np.array_equal(a.t_reach, b.t_reach)
    assert a.end_reason.tolist() == b.end_reason.tolist() and np.array_equal(a.end_step, b.end_step)
    np.testing.assert_allclose(a.returns, b.returns, rtol=1e-9)
    np.testing.assert_allclose(a.trajectories, b.trajectories, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(a.rho, b.rho, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(a.actions, b.actions, rtol=1e-9, atol=1e-12)  # of states equal to 1e-12
