"""The specs written to test whether the default training generalises (issue 18):
examples/pendulum_swingup.asap (energy pumping), examples/puck_detour.asap and
examples/rover_detour.asap (detours round an obstacle), examples/planar_quadrotor.asap (an
under-actuated craft), examples/cartpole_swingup.asap (energy pumping, under-actuated) and
examples/dubins_turnaround.asap (a car that cannot stop, its goal behind it). Each loads, lints clean, steps finitely, and the oracle's action sequences for two
states, replayed in the training environment from the same start, reach the goal at the step the
oracle says without touching the obstacle."""

from __future__ import annotations

import numpy as np
import pytest

import asap_dsl
from asap_dsl.backends import oracle as O
from asap_dsl.sampling import init_box, task_states
from conftest import ROOT, asapc

PENDULUM = ROOT / "examples" / "pendulum_swingup.asap"
PUCK = ROOT / "examples" / "puck_detour.asap"
ROVER = ROOT / "examples" / "rover_detour.asap"
QUADROTOR = ROOT / "examples" / "planar_quadrotor.asap"
CARTPOLE = ROOT / "examples" / "cartpole_swingup.asap"
DUBINS = ROOT / "examples" / "dubins_turnaround.asap"
SPECS = [PENDULUM, PUCK, ROVER, QUADROTOR, CARTPOLE, DUBINS]
CASES = [(PENDULUM, "reach"), (PUCK, "reach"), (PUCK, "reach_avoid"), (ROVER, "reach_avoid"),
         (QUADROTOR, "reach"), (QUADROTOR, "reach_avoid"), (CARTPOLE, "reach"), (DUBINS, "reach")]


@pytest.mark.parametrize("spec", SPECS, ids=lambda p: p.stem)
def test_lint_is_clean(capsys, spec):
    code, out, _ = asapc(capsys, "lint", str(spec))
    assert code == 0 and "0 errors, 0 warnings" in out


@pytest.mark.parametrize("spec, task", CASES, ids=lambda c: getattr(c, "stem", c))
def test_one_step_is_finite(spec, task):
    env = asap_dsl.make_env(spec, task=task, seed=0)
    obs, _ = env.reset()
    middle = (env.action_space.low + env.action_space.high) / 2  # a random brake at the rover's v = 0 would leave its space
    obs, reward, terminated, truncated, info = env.step(middle)
    assert np.isfinite(obs).all() and np.isfinite(reward) and not terminated and not truncated
    assert info["end_reason"] is None, info


def test_the_torque_cannot_lift_the_pendulum_directly():
    """The point of the spec: |u| is below m g l, so upright is reached only by pumping."""
    prog = asap_dsl.load(PENDULUM)
    c = prog.system.consts
    assert prog.system.action_high[0] < c["m"] * c["g0"] * c["l"] / 3


def test_the_cart_pole_swings_away_from_upright_first():
    """The point of the spec: on the oracle's minimum-time path from a start of the box, the pole's
    angle from upright grows again before it arrives (a pump): the full force accelerates the
    cart at less than half of g, too little to throw the pole up in one push."""
    prog = asap_dsl.load(CARTPOLE)
    c = prog.system.consts
    assert prog.system.action_high[0] / (c["mc"] + c["mp"]) < c["g0"] / 2
    x0 = task_states(prog.system, prog.task("reach").model, 1, seed=2024)[0]
    r = O.Oracle(prog, "reach", time_limit=30.0).solve(x0)
    assert r.status == "solved" and r.steps > 20, r
    from_upright = np.pi - np.abs(np.asarray(r.trajectory)[:, 1])  # theta = +-pi upright
    assert (np.diff(from_upright) > 0.05).any(), from_upright


def test_the_rover_must_go_over_the_crater():
    """The point of the spec: from every start the straight line to the goal crosses the crater,
    and below it the crater reaches the edge of the state space, so the only way is over its rim,
    away from the goal's height."""
    prog = asap_dsl.load(ROVER)
    crater, goal = prog.regions["crater"], prog.regions["goal"]
    c, r = np.array(crater.centre), crater.radius
    starts = task_states(prog.system, prog.task("reach_avoid").model, 200, seed=0)[:, :2]
    s = np.linspace(0, 1, 101)[:, None, None]
    lines = starts[None] + s * (np.array(goal.centre) - starts)[None]  # [point, start, xy]
    assert (np.linalg.norm(lines - c, axis=-1) < r).any(axis=0).all()
    assert np.linalg.norm(starts - c, axis=-1).min() > r and np.linalg.norm(np.array(goal.centre) - c) > r + goal.radius
    y_low = prog.system.state_low[1]
    assert r ** 2 - (y_low - c[1]) ** 2 > 3.8 ** 2  # the disc covers the bottom edge for |x| < 3.8


def test_the_dubins_car_drives_away_from_its_goal_first():
    """The point of the spec: from every corner of the start box the car's first motion takes it
    further from the goal (it cannot stop nor reverse, and heads within 45 degrees of away), and
    on the oracle's minimum-time path it comes back only after a loop."""
    prog = asap_dsl.load(DUBINS)
    goal = np.array(prog.regions["goal"].centre)
    low, high = init_box(prog.system, prog.task("reach").model.init_box)
    corners = np.array(np.meshgrid(*[[lo, hi] for lo, hi in zip(low, high)])).reshape(3, -1).T
    away = ((corners[:, :2] - goal) * np.stack([np.cos(corners[:, 2]), np.sin(corners[:, 2])], axis=1)).sum(axis=1)
    assert (away > 0).all(), away  # d/dt |p - goal|^2 / 2 = (p - goal) . v at the start
    x0 = task_states(prog.system, prog.task("reach").model, 1, seed=2024)[0]
    r = O.Oracle(prog, "reach", time_limit=30.0).solve(x0)
    assert r.status == "solved", r
    distance = np.linalg.norm(np.asarray(r.trajectory)[:, :2] - goal, axis=1)
    assert distance.max() > distance[0] + 1.0 and r.steps > 30, (distance, r.steps)


def _replay(spec, task: str, x0: np.ndarray, actions: np.ndarray):
    """The first step at which the environment says `asap` held, and the end reason, when the
    episode starts at ``x0`` and takes ``actions``."""
    env = asap_dsl.make_env(spec, task=task, seed=0)
    env.reset()
    core = env.unwrapped.core
    core.start(x0[None], core.k[0])
    for a in actions:
        _, _, terminated, _, info = env.step(a)
        if terminated:
            return info["t_reach"], info["end_reason"]
    return info["t_reach"], info["end_reason"]


# The pendulum's two starts swing faster than the init box's (omega 4, not 2): one pump brings
# them up in 34 steps, which the oracle decides in about a second; a start from the box takes 3-20 s.
STARTS = {(PENDULUM, "reach"): np.array([[1.0, 4.0], [-1.0, -4.0]])}


@pytest.mark.parametrize("spec, task", CASES, ids=lambda c: getattr(c, "stem", c))
def test_oracle_sequences_replay_to_the_oracles_step(spec, task):
    prog = asap_dsl.load(spec)
    states = STARTS.get((spec, task))
    if states is None:
        states = task_states(prog.system, prog.task(task).model, 2, seed=2024)
    oracle = O.Oracle(prog, task, time_limit=30.0)
    for x0 in states:
        r = oracle.solve(x0)
        assert r.status == "solved" and r.verified, r
        t_reach, end = _replay(spec, task, x0, np.asarray(r.actions))
        assert t_reach == r.steps and end in (None, "time_limit"), (x0, t_reach, r.steps, end)
