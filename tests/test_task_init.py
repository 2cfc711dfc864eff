"""A task's own initial box (`init box(...)`): checked like a state's `init`, and used instead of
the system's by training environments, evaluation, the oracle and `lint --deep`."""

from __future__ import annotations

import numpy as np
import pytest

import asap_dsl
from asap_dsl.sampling import task_states
from conftest import diagnostics, position

PENDULUM = """\
system Pendulum {
  const g = 9.81
  state theta in [-4, 4] init [-3.14, 3.14]
  state omega in [-8, 8] init [-1, 1]
  action u in [-2, 2]
  dt = 0.05
  ode { theta' = omega, omega' = -g * sin(theta) + u }
}
region upright = box(theta in [-0.15, 0.15], omega in [-0.5, 0.5])
task stabilise {
  init box(theta in [-0.3, 0.3])
  asap in upright
  deadline 3s
}
task swing_up {
  init box(theta in [3, 3.14], omega in [-0.1, 0.1])
  asap in upright
  deadline 5s
}
task anywhere { asap in upright  deadline 5s }
"""


def test_each_task_draws_from_its_own_box_and_the_others_from_the_systems():
    prog = asap_dsl.loads(PENDULUM)
    boxes = {"stabilise": ([-0.3, -1], [0.3, 1]), "swing_up": ([3, -0.1], [3.14, 0.1]),
             "anywhere": ([-3.14, -1], [3.14, 1])}
    for name, (lo, hi) in boxes.items():
        states = task_states(prog.system, prog.task(name).model, 2000, seed=1)
        assert np.all(states >= lo) and np.all(states <= hi)
        assert np.allclose(states.min(0), lo, atol=0.05) and np.allclose(states.max(0), hi, atol=0.05)
        env = asap_dsl.make_vec_env(prog, task=name, num_envs=64, seed=0)
        obs = env.reset()
        assert np.all(obs >= np.float32(lo) - 1e-6) and np.all(obs <= np.float32(hi) + 1e-6)


def test_the_oracle_and_evaluation_use_the_tasks_box():
    from asap_dsl.backends.oracle.solver import run

    prog = asap_dsl.loads(PENDULUM)
    rep = run(prog, "stabilise", episodes=6, workers=1)
    xs = np.array([r.x0 for r in rep.results])
    assert np.all(np.abs(xs[:, 0]) <= 0.3)
    assert np.allclose(xs, task_states(prog.system, prog.task("stabilise").model, 6))


@pytest.mark.parametrize("box, code, at", [
    ("box(theta in [-5, 0])", "E108", "[-5, 0]"),
    ("box(omega in [-inf, 0])", "E108", "[-inf, 0]"),
    ("box(u in [0, 1])", "E103", "u in [0, 1]"),
    ("box(thta in [0, 1])", "E101", "thta"),
    ("box(theta in [0, 1], theta in [0, 0.5])", "E102", "theta in [0, 0.5]"),
    ("box(theta in [1, 0])", "E105", "[1, 0]"),
])
def test_a_tasks_box_is_checked_like_a_states_init(box, code, at):
    src = PENDULUM.replace("init box(theta in [-0.3, 0.3])", f"init {box}")
    found = [d for d in diagnostics(src) if d.is_error]
    assert [d.code for d in found] == [code], found
    assert (found[0].line, found[0].column) == position(src, at)


def test_init_inside_avoid_is_judged_on_the_tasks_box():
    src = PENDULUM.replace("task anywhere { asap in upright  deadline 5s }",
                           "region low = box(theta in [-0.5, 0.5])\n"
                           "task inside { init box(theta in [-0.3, 0.3])  asap in upright  avoid in low  deadline 5s }")
    assert "E123" in [d.code for d in diagnostics(src)]
    assert "E123" not in [d.code for d in diagnostics(src.replace("avoid in low", "avoid theta > 3.5"))]


def test_show_prints_the_tasks_box():
    from asap_dsl.cli import show_data

    data = show_data(asap_dsl.loads(PENDULUM))
    assert data["tasks"]["swing_up"]["init"] == [[3.0, 3.14], [-0.1, 0.1]]
    assert data["tasks"]["anywhere"]["init"] is None
