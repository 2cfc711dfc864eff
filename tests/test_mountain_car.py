"""examples/mountain_car.asap is gymnasium's MountainCarContinuous-v0: lint is clean, the spec's
step is gymnasium's step (the wall reset included), and the oracle's action sequences, replayed in
gymnasium's own environment from the same start, reach the goal at the step the oracle says."""

from __future__ import annotations

import numpy as np
import pytest

import asap_dsl
from asap_dsl.backends import oracle as O
from asap_dsl.dynamics import casadi_step, numpy_step
from asap_dsl.sampling import task_states
from conftest import ROOT, asapc

gymnasium = pytest.importorskip("gymnasium")

SPEC = ROOT / "examples" / "mountain_car.asap"


@pytest.fixture(scope="module")
def prog():
    return asap_dsl.load(SPEC)


def _gym(state):
    env = gymnasium.make("MountainCarContinuous-v0")
    env.reset(seed=0)
    env.unwrapped.state = np.array(state, dtype=np.float32)
    return env


def test_lint_is_clean_and_the_spec_counts_in_steps(capsys, prog):
    code, out, _ = asapc(capsys, "lint", str(SPEC))
    assert code == 0 and "0 errors, 0 warnings" in out
    assert prog.system.kind == "map" and prog.system.dt is None and prog.task("reach").deadline == 200


def test_the_step_is_gymnasiums_wall_included(prog):
    """Random actions (beyond the bounds too) from states over the whole track, starts at the wall
    moving left among them: one step of the spec is gymnasium's step, to gymnasium's float32."""
    rng = np.random.default_rng(0)
    starts = np.column_stack([rng.uniform(-1.2, 0.6, 300), rng.uniform(-0.07, 0.07, 300)]).astype(np.float32)
    starts[:20] = [-1.19, -0.07]
    actions = rng.uniform(-1.5, 1.5, (300, 1)).astype(np.float32)
    ours = numpy_step(prog.system)(starts.astype(np.float64), np.clip(actions, -1, 1).astype(np.float64))
    theirs = []
    for s, a in zip(starts, actions):
        env = _gym(s)
        theirs.append(env.step(a)[0])
    theirs = np.array(theirs, dtype=np.float64)
    np.testing.assert_allclose(ours, theirs, atol=1e-7)
    assert (theirs[:20] == [np.float32(-1.2), 0.0]).all() and (ours[:20] == [-1.2, 0.0]).all()  # stopped at the wall
    # The oracle's step (CasADi: fmin/fmax for clip, if_else for the wall) is the same function.
    step = casadi_step(prog.system)
    for s, a, want in zip(starts[:40].astype(np.float64), actions[:40], ours[:40]):
        got = np.array(step(s, np.clip(a, -1, 1))).ravel()
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)


def test_oracle_sequences_reach_the_goal_in_gymnasium_at_the_oracles_step(prog):
    # Starts representable in float32, gymnasium's state type, so that both begin at the same point.
    states = task_states(prog.system, prog.task("reach").model, 3, seed=7).astype(np.float32).astype(np.float64)
    oracle = O.Oracle(prog, "reach", time_limit=60.0)  # about 5 s each when the machine is quiet
    for x0 in states:
        r = oracle.solve(x0)
        assert r.status == "solved" and r.verified and 60 <= r.steps <= 70, r
        env = _gym(x0)
        reached = None
        for k, a in enumerate(np.asarray(r.actions, dtype=np.float32), start=1):
            _, _, terminated, truncated, _ = env.step(a)
            if terminated:
                reached = k
                break
        assert reached == r.steps, (x0, reached, r.steps)
