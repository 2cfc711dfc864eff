"""The sampling planner (issue 17): it finds minima known in closed form, through known dynamics
and through a black box; only what the replay confirms counts; a simulator that cannot be started
from a given state is one sentence."""

from __future__ import annotations

import io
import json
import math
import time
from pathlib import Path

import numpy as np
import pytest

import asap_dsl
from asap_dsl.backends.oracle.planner import BOUND, PlannedState, Planner, PlannerBudget, PlannerUnsupported
from asap_dsl.backends.oracle.planning import plan_states, replay_counted
from asap_dsl.cli import main
from conftest import RAIL

FIXTURES = Path(__file__).resolve().parent / "fixtures"
SMALL = PlannerBudget(samples=32, iterations=12, pilot=1)

CART = """
system Cart {
  state x in [-10, 10] init [-1, 1]
  state v in [-5, 5]   init [-1, 1]
  action u in [-2, 2]
  dt = 0.1
  simulator "%s"
}
region goal = ball({x: 3}, 0.5)
task reach {
  asap in goal
  deadline 40
}
"""


@pytest.fixture
def user_sims(monkeypatch):
    monkeypatch.syspath_prepend(str(FIXTURES))
    import user_sims

    return user_sims


def rail_minimum(x0: float) -> int:
    """The rail moves at most 0.2 per step (x' = 2u, |u| <= 1, dt 0.1) into [0.8, 1.2]."""
    gap = abs(x0 - 1.0) - 0.2
    return 0 if gap <= 0 else math.ceil(gap / 0.2 - 1e-9)


def cart_minimum(x0: float, v0: float) -> int:
    """Full thrust (u = 2) maximises x at every step (x_N is increasing in every action), so the
    first N with x0 + v0 N dt + (N dt)^2 >= 2.5 is the minimum (the steps are shorter than the
    goal's width, so that N lands in it)."""
    for n in range(0, 41):
        t = 0.1 * n
        if x0 + v0 * t + t * t >= 2.5:
            return n
    raise AssertionError("beyond the deadline")


def test_planner_finds_the_rails_minimum():
    prog = asap_dsl.loads(RAIL, "rail.asap")
    rep = plan_states(prog, "go", episodes=12, budget=SMALL)
    assert rep.label == "achievable" and rep.to_dict()["bound"] == BOUND == "planner (achievable)"
    for r in rep.results:
        assert r.verified and r.steps == rail_minimum(float(r.x0[0])), (r.x0, r.steps)


def test_planner_finds_a_black_box_double_integrators_minimum(user_sims):
    prog = asap_dsl.loads(CART % "user_sims:double_integrator", "cart.asap")
    rep = plan_states(prog, "reach", episodes=8, budget=SMALL, workers=2)
    for r in rep.results:
        assert r.verified and r.steps == cart_minimum(*map(float, r.x0)), (r.x0, r.steps)
    # the same results in one process: a state's search depends on it alone
    one = plan_states(prog, "reach", episodes=8, budget=SMALL, workers=1)
    assert [r.steps for r in one.results] == [r.steps for r in rep.results]


def test_a_sequence_the_replay_does_not_confirm_is_not_counted():
    prog = asap_dsl.loads(RAIL, "rail.asap")
    x0 = np.array([0.0])  # 4 steps of u = 1 reach the goal
    claims = [PlannedState(0, x0, 2, "solved", False, actions=np.zeros((2, 1))),      # stays: never reaches
              PlannedState(1, x0, 7, "solved", False, actions=np.ones((7, 1))),       # reaches sooner than claimed
              PlannedState(2, x0, 5, "solved", False, actions=-np.ones((5, 1)))]      # away from the goal
    out = replay_counted(prog, "go", claims)
    assert [(r.steps, r.status, r.verified) for r in out] == [(None, "unverified", False), (4, "solved", True),
                                                               (None, "unverified", False)]
    assert out[1].actions.shape == (4, 1)


def test_a_simulator_that_cannot_be_set_to_a_state_is_one_sentence(user_sims, tmp_path, capsys):
    prog = asap_dsl.loads(CART % "user_sims:own_start", "cart.asap")
    with pytest.raises(PlannerUnsupported) as err:
        Planner(prog, "reach", SMALL)
    text = str(err.value)
    assert "cart.asap:7:3:" in text and "cannot be started from a given state" in text
    assert "reset(states [B, n])" in text and text.count(". ") == 0 and "\n" not in text
    spec = tmp_path / "cart.asap"
    spec.write_text(CART % "user_sims:own_start")
    code = main(["oracle", str(spec), "--episodes", "2", "--samples", "8", "--iterations", "1"])
    captured = capsys.readouterr()
    assert code == 1 and "Traceback" not in captured.err
    assert "task reach is not solved" in captured.err and "cannot be started from a given state" in captured.err


def test_oracle_command_plans_a_black_box_and_stores_it_for_eval(user_sims, tmp_path, monkeypatch):
    monkeypatch.setenv("ASAP_CACHE_DIR", str(tmp_path / "cache"))
    spec = tmp_path / "cart.asap"
    spec.write_text(CART % "user_sims:double_integrator")
    out = io.StringIO()
    from asap_dsl.cli import build_parser

    args = build_parser().parse_args(["oracle", str(spec), "--episodes", "3", "--samples", "16", "--iterations",
                                      "4", "--format", "json", "--workers", "1"])
    assert args.func(args, out=out, err=io.StringIO()) == 0
    d = json.loads(out.getvalue())["tasks"][0]
    assert d["bound"] == "planner (achievable)" and d["label"] == "achievable"
    assert d["planner"]["samples"] == 16 and d["planner"]["iterations"] == 4
    from asap_dsl.backends.oracle.cache import oracle_for

    cached = oracle_for(asap_dsl.load(spec), "reach", 2024, 3)
    assert cached is not None and cached.bound == "planner (achievable)"
    text = io.StringIO()
    args = build_parser().parse_args(["oracle", str(spec), "--episodes", "3", "--samples", "16", "--iterations", "4"])
    args.func(args, out=text, err=io.StringIO())
    assert "planner (achievable)" in text.getvalue() and "lower bound on the ceiling" in text.getvalue()


def test_the_pilots_shortening_finds_the_rails_minimum_from_a_slow_sequence():
    """A slow sequence (u = 0.3: 14 steps from x = 0) is shortened to the rail's minimum (4 steps
    of full speed), and every sequence on the way reaches where it says (replayed)."""
    prog = asap_dsl.loads(RAIL, "rail.asap")
    planner = Planner(prog, "go", PlannerBudget(samples=64))
    found, used = planner.shorten(np.zeros(1), np.full((14, 1), 0.3), time.perf_counter() + 30)
    assert len(found[0]) == 14 and len(found[-1]) == rail_minimum(0.0) and used > 0
    claims = [PlannedState(i, np.zeros(1), len(a), "solved", False, actions=a) for i, a in enumerate(found)]
    assert [(r.steps, r.verified) for r in replay_counted(prog, "go", claims)] == [(len(a), True) for a in found]


def test_the_polish_finds_and_shortens_where_the_sampling_found_nothing():
    """With nothing from the sampling (no archive either), the polish's descents from fresh
    proposals reach and its shortening ends at the rail's closed-form minimum (replayed)."""
    prog = asap_dsl.loads(RAIL, "rail.asap")
    planner = Planner(prog, "go", PlannerBudget(samples=64))
    x0 = np.array([-0.6])
    actions, used = planner.polish(x0, None, [], np.random.default_rng(0), math.inf, time.perf_counter() + 30)
    assert actions is not None and len(actions) == rail_minimum(-0.6) and used > 0
    claim = PlannedState(0, x0, len(actions), "solved", False, actions=actions)
    assert replay_counted(prog, "go", [claim])[0].steps == rail_minimum(-0.6)


def test_the_shortenings_clock_is_bounded_and_finding_keeps_the_whole_budget():
    """``shorten_seconds`` bounds the shortening of a found sequence (0: kept as found, no
    rollout spent), never the search where nothing reached: with it at 0 the polish still finds a
    sequence from nothing. A negative bound is one sentence."""
    prog = asap_dsl.loads(RAIL, "rail.asap")
    planner = Planner(prog, "go", PlannerBudget(samples=64, shorten_seconds=0.0))
    slow = np.full((14, 1), 0.3)
    actions, used = planner.polish(np.zeros(1), slow, [], np.random.default_rng(0), math.inf, time.perf_counter() + 30)
    assert used == 0 and np.array_equal(actions, slow)
    actions, used = planner.polish(np.array([-0.6]), None, [], np.random.default_rng(0), math.inf,
                                   time.perf_counter() + 30)
    assert actions is not None and used > 0 and len(actions) >= rail_minimum(-0.6)
    with pytest.raises(ValueError, match="shorten_seconds must be a finite number, at least 0"):
        PlannerBudget(shorten_seconds=-1.0)


def test_on_the_simulated_clock_a_slower_machine_searches_the_same():
    """With ``steps_per_second`` the time limit is read in simulator steps rolled out, not on
    the wall clock: a planner whose simulator is slowed down stops at the same iteration and
    finds the same sequence (a training run's demonstrations are the same on every machine)."""
    prog = asap_dsl.loads(RAIL, "rail.asap")
    budget = PlannerBudget(samples=32, iterations=10_000, polish=0.0, steps_per_second=20_000.0)
    fast, slow = Planner(prog, "go", budget, time_limit=0.5), Planner(prog, "go", budget, time_limit=0.5)
    rollout = slow.evaluator.run

    def sluggish(*args, **kwargs):
        time.sleep(0.002)
        return rollout(*args, **kwargs)

    slow.evaluator.run = sluggish
    x0 = np.array([-0.6])
    a, b = fast.plan(x0), slow.plan(x0)
    assert (a.status, a.steps, a.rollouts, a.iterations) == (b.status, b.steps, b.rollouts, b.iterations)
    assert np.array_equal(a.actions, b.actions) and fast.rolled == slow.rolled
    assert a.steps == rail_minimum(-0.6) and a.iterations < 10_000  # the clock ended it, not the iterations
    assert 10_000 < fast.rolled <= 10_000 + 32 * 20  # 0.5 s at 20,000 steps a second, and one batch more
    with pytest.raises(ValueError, match="steps_per_second must be a finite number, at least 0"):
        PlannerBudget(steps_per_second=-1.0)


def test_a_wall_clock_cap_leaves_out_the_states_not_begun():
    """``budget_seconds`` caps the wall clock whatever the budget's clock (a training run's time
    limit): a spent cap begins no state and the report holds none; a cap far off changes nothing."""
    prog = asap_dsl.loads(RAIL, "rail.asap")
    budget = PlannerBudget(samples=32, iterations=12, pilot=1, steps_per_second=20_000.0)
    free = plan_states(prog, "go", episodes=6, budget=budget)
    far = plan_states(prog, "go", episodes=6, budget=budget, budget_seconds=1e6)
    spent = plan_states(prog, "go", episodes=6, budget=budget, budget_seconds=0.0)
    assert [r.steps for r in far.results] == [r.steps for r in free.results] and len(free.results) == 6
    assert spent.results == [] and spent.ceiling(20)["states"] == 0


def test_the_planners_workers_are_spawned_not_forked(monkeypatch):
    """A worker forked from a process that has stepped MuJoCo inherits its thread pool, and
    freeing it there waits in pthread_cond_destroy for threads that exist only in the parent, for
    ever (the swimmer's second task hung so: reproduced with a forked pool whose child runs
    ``gc.collect()`` over an inherited ``MujocoSwimmer(nthread=2)``; spawned, it finishes). The
    collection's timing is not the test's to choose, so this asserts the start method itself."""
    import multiprocessing as mp

    asked = []
    real = mp.get_context
    monkeypatch.setattr(mp, "get_context", lambda method=None: asked.append(method) or real(method))
    rep = plan_states(asap_dsl.loads(RAIL, "rail.asap"), "go", episodes=4, budget=SMALL, workers=2)
    assert len(rep.results) == 4 and asked and set(asked) == {"spawn"}
