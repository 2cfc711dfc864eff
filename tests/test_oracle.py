"""The CasADi minimum-time oracle (asap_dsl.backends.oracle.solver): closed forms, DC motor, replay,
obstacles, unreachable goals, unsupported inputs and the command."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import time

import numpy as np
import pytest

import asap_dsl
from asap_dsl.backends import oracle as O
from asap_dsl.cli.oracle import add_oracle_arguments
from asap_dsl.dynamics import numpy_step, zero_order_hold
from asap_dsl.stl import offline

SPECS = Path(__file__).resolve().parents[1] / "specs"

# x'' = u, |u| <= 1, exact zero-order hold with dt = 1: rest-to-rest over a distance D takes the
# fewest steps N with max_N >= D, where max_N = N^2/4 (N even: bang-bang, +1 then -1) and
# (N^2 - 1)/4 (N odd: +1, one 0, -1), from p_N - p_0 = sum_j u_j (N - j - 1/2), v_N = sum_j u_j.
DOUBLE_INTEGRATOR_ODE = """
system DoubleIntegrator {
  state p in [-20, 20] init [-10, -1]
  state v in [-20, 20] init [-1, 1]
  action u in [-1, 1]
  dt = 1
  integrator exact
  ode {
    p' = v
    v' = u
  }
}
region goal = ball([0, 0], 0.05)
task rest { asap in goal  deadline 12  tolerances 12, 6, 4 }
"""

# The discrete double integrator p+ = p + v, v+ = v + u, |u| <= 1, from rest: after k steps
# p_k - p_0 = sum_{j <= k-2} (k-1-j) u_j ranges over [-k(k-1)/2, k(k-1)/2], so reaching a box
# |p| <= 0.01 (v free) from p0 = -D takes the fewest k with k(k-1)/2 >= D - 0.01.
DOUBLE_INTEGRATOR_MAP = """
system DiscreteDoubleIntegrator {
  state p in [-50, 50]
  state v in [-50, 50]
  action u in [-1, 1]
  dt = 1
  map {
    p = p + v
    v = v + u
  }
}
region goal = box(p in [-0.01, 0.01])
task reach { asap in goal  deadline 12 }
"""

# A single integrator in the plane around a large disc: the straight line goes through it.
PLANE = """
system Plane {
  state x in [-10, 10] init [-5, -5]
  state y in [-10, 10] init [0, 0]
  action ux in [-1, 1]
  action uy in [-1, 1]
  dt = 1
  map {
    x = x + ux
    y = y + uy
  }
}
region goal = ball([5, 0], 0.5)
region disc = ball([0, 0], 4.5)
task reach { asap in goal  deadline 30 }
task reach_avoid { asap in goal  avoid in disc  deadline 30 }
task far { asap in goal  deadline 5 }
task cmp { asap x > 4  deadline 30 }
task temporal { asap once[0, 3] in goal  deadline 30 }
task either { asap in goal or in disc  deadline 30 }
"""


def dc_motor(volts: float, init: str = "") -> asap_dsl.Program:
    src = (SPECS / "dc_motor.asap").read_text()
    line = "action V     in [-20, 20]"
    assert line in src
    return asap_dsl.loads(src.replace(line, f"action V     in [-{volts}, {volts}]"), f"dc_motor_{volts}V")


def rest_to_rest_steps(D: float) -> int:
    N = 1
    while (N * N / 4 if N % 2 == 0 else (N * N - 1) / 4) < D:
        N += 1
    return N


def test_double_integrator_ode_matches_bang_bang():
    prog = asap_dsl.loads(DOUBLE_INTEGRATOR_ODE)
    oracle = O.Oracle(prog, "rest")
    assert oracle.label == "exact"
    for D in (1.5, 3.5, 5.5, 8.5, 11.5):
        r = oracle.solve([-D, 0.0])
        assert r.status == "solved" and r.verified
        assert r.steps == rest_to_rest_steps(D), (D, r.steps)
        assert np.all(np.abs(r.actions) <= 1 + 1e-9)


def test_double_integrator_map_matches_closed_form():
    prog = asap_dsl.loads(DOUBLE_INTEGRATOR_MAP)
    oracle = O.Oracle(prog, "reach")
    assert oracle.label == "exact"
    for D, want in ((0.5, 2), (3.0, 3), (6.5, 5), (10.0, 5), (20.0, 7)):
        r = oracle.solve([-D, 0.0])
        assert (r.steps, r.verified) == (want, True), (D, r.steps)
    assert oracle.solve([0.0, 3.0]).steps == 0  # already in the goal


def test_dc_motor_from_origin():
    # BENCHMARKS.md: 150 V needs 6 steps. For 10 V it lists 20, but under the project's own
    # discretisation (exact ZOH, ball over (theta, omega, i) r 0.5) 19 steps suffice; an
    # independent bounded least-squares solve (scipy BVLS) below confirms 18 is too few and 19 enough.
    from scipy.optimize import lsq_linear

    for volts, want in ((150, 6), (10, 19)):
        prog = dc_motor(volts)
        r = O.Oracle(prog, "reach").solve([0.0, 0.0, 0.0])
        assert (r.steps, r.status, r.verified) == (want, "solved", True)
        Ad, Bd, _ = zero_order_hold(prog.system)
        c = np.array([math.pi / 2, 0, 0])
        for N, ok in ((want - 1, False), (want, True)):
            G = np.hstack([np.linalg.matrix_power(Ad, N - 1 - k) @ Bd for k in range(N)])
            best = lsq_linear(G, c, bounds=(-volts, volts), method="bvls", tol=1e-12)
            assert (np.linalg.norm(G @ best.x - c) <= 0.5) == ok


def test_replay_reaches_goal_and_avoids_obstacle():
    prog = asap_dsl.loads(PLANE)
    free, avoid = O.Oracle(prog, "reach"), O.Oracle(prog, "reach_avoid")
    assert (free.label, avoid.label) == ("exact", "local")
    x0 = [-5.0, 0.0]
    a, b = free.solve(x0), avoid.solve(x0)
    assert a.steps == 10 and a.verified
    assert b.status == "solved" and b.verified and b.steps > a.steps
    step = numpy_step(prog.system)
    traj = [np.asarray(x0)]
    for u in b.actions:
        traj.append(step(traj[-1][None], np.clip(u, -1, 1)[None])[0])
    traj = np.asarray(traj)
    np.testing.assert_allclose(traj, b.trajectory, atol=1e-9)
    assert prog.regions["goal"].satisfied(traj[-1])
    assert not prog.regions["disc"].satisfied(traj).any()
    # and the DC motor's reach_avoid from the origin (20 V): goal at N, obstacle never touched
    dc = asap_dsl.load(SPECS / "dc_motor.asap")
    r = O.Oracle(dc, "reach_avoid").solve([0.0, 0.0, 0.0])
    assert r.verified and dc.regions["goal"].satisfied(r.trajectory[-1])
    assert not dc.regions["unsafe"].satisfied(r.trajectory).any()


def test_unreachable_goal_is_reported():
    prog = asap_dsl.loads(PLANE)
    r = O.Oracle(prog, "far").solve([-5.0, 0.0])
    assert (r.steps, r.status, r.verified) == (None, "infeasible", False)
    rep = O.run(prog, "far", states=np.array([[-5.0, 0.0], [4.0, 0.0]]))
    assert rep.to_dict()["unreachable_within_deadline"] == 1
    assert rep.ceiling(5)["count"] == 1
    bad = O.deadline_infeasible(prog, "far", samples=4)
    assert len(bad) == 4 and bad[0][1] == "infeasible" and "proved by a convex problem" in bad[0][2]
    assert O.deadline_infeasible(prog, "reach", samples=4) == []


def test_the_search_of_a_state_is_bounded_in_time():
    # an unreachable goal with a deadline of a million steps: a timeout, not days of search
    # z never moves: the goal z in [1, 2] is never reached, which only the search can find out
    prog = asap_dsl.loads("system Stuck {\n  state x in [-10, 10] init [-5, -5]\n  state z in [-5, 5] init [0, 0]\n"
                          "  action u in [-1, 1]\n  dt = 1\n  map { x = x + u, z = z }\n}\n"
                          "region up = box(z in [1, 2])\ntask never { asap in up  deadline 1000000 }\n")
    far = "never"
    t0 = time.perf_counter()
    r = O.Oracle(prog, far, time_limit=1.0).solve([-5.0, 0.0])
    assert time.perf_counter() - t0 < 5
    assert (r.steps, r.status, r.verified) == (None, "timeout", False) and r.horizon >= 1
    rep = O.run(prog, far, states=np.array([[-5.0, 0.0]]), time_limit=0.5)
    assert rep.counts()["timeout"] == 1 and rep.to_dict()["states"][0]["horizon"] >= 1
    assert rep.ceiling(5)["count"] == 0
    with pytest.raises(ValueError, match="positive number of seconds"):
        O.Oracle(prog, far, time_limit=0)


def test_disjunctive_goal_and_nan_state():
    prog = asap_dsl.loads(PLANE)
    oracle = O.Oracle(prog, "either")
    assert oracle.solve([-5.0, 0.0]).steps == 1  # the disc is one step away
    assert oracle.solve([np.nan, 0.0]).status == "nan"


def test_unsupported_inputs_are_clear():
    prog = asap_dsl.loads(PLANE + "task with_since { asap in goal since x > 0  deadline 30 }\n"
                          "task past_avoid { asap in goal  avoid once[0, 2] in disc  deadline 30 }\n"
                          "task wide { asap once[0, 20] in goal and once[0, 20] x > 4  deadline 30 }\n")
    for task, words in (("with_since", "`since`"), ("past_avoid", "`once` in `avoid`"), ("wide", "more than 64 alternatives")):
        with pytest.raises(O.OracleUnsupported, match=words):
            O.Oracle(prog, task)
    swimmer = asap_dsl.load(SPECS / "swimmer.asap")
    with pytest.raises(O.OracleUnsupported, match="needs an ode or map system"):
        O.Oracle(swimmer, "reach")


def test_comparisons_and_past_operators_are_solved_and_verified():
    prog = asap_dsl.loads(PLANE)
    start = np.array([[-5.0, 0.0], [-3.0, 2.0]])
    cmp = O.run(prog, "cmp", states=start)  # x > 4: from x = -5 at |ux| <= 1, 10 steps (x = 5 > 4)
    assert [r.steps for r in cmp.results] == [10, 8] and all(r.verified for r in cmp.results)
    assert O.Oracle(prog, "cmp").label == "exact"  # a half-plane: convex
    once = O.run(prog, "temporal", states=start)  # once[0, 3] in goal: as soon as the goal is reached
    plain = O.run(prog, "reach", states=start)
    assert [r.steps for r in once.results] == [r.steps for r in plain.results]


def _passes(o, tr):
    """The definition, prefix by prefix: finite, inside the state space at steps 1..N, ``asap`` at
    N (evaluated on this prefix alone), ``avoid`` at none of steps 1..N."""
    t, N = o.task.model, tr.shape[0] - 1
    return bool(np.all(np.isfinite(tr)) and np.all(tr[1:] >= o.low) and np.all(tr[1:] <= o.high)
                and offline.satisfied(t.asap, tr[None])[0, N]
                and (t.avoid is None or N == 0 or not np.any(offline.satisfied(t.avoid, tr[None])[0, 1:])))


def _first_passing_by_prefixes(o, tr):
    """The smallest k >= 1 whose prefix tr[:k + 1] passes (:func:`_passes`), none past a non-finite state."""
    for k in range(1, tr.shape[0]):
        if not np.all(np.isfinite(tr[k])):
            return None
        if _passes(o, tr[: k + 1]):
            return k
    return None


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # random actions overflow attitude's finite escape
@pytest.mark.parametrize("source, task", [(SPECS / "attitude.asap", "reach_avoid"), (None, "settle")])
def test_the_searchs_prefix_check_is_the_replays(source, task):
    """The search checks each solution's prefixes in one pass over a CasADi rollout; it must
    agree with the replay through the simulator's step and the prefix-by-prefix check (an
    ``avoid``, the state space and a dwell over past steps included)."""
    prog = asap_dsl.load(source) if source is not None else asap_dsl.loads(DWELL)
    o = O.Oracle(prog, task, restarts=0)
    rng = np.random.default_rng(3)
    low, high = prog.system.init_low, prog.system.init_high
    found, late = 0, None
    for _ in range(60):
        x0 = rng.uniform(low, high) * rng.choice([0.1, 0.5, 1.0])
        U = rng.uniform(o.ulow, o.uhigh, size=(int(rng.integers(1, 25)), o.m)) * rng.choice([0.0, 0.3, 1.0])
        tr, _ = o.replay(x0, U)
        assert np.allclose(o._rollout(x0, U), tr, rtol=1e-9, atol=1e-9, equal_nan=True)
        expected = _first_passing_by_prefixes(o, tr)
        assert o.passing_prefix(tr) == o.first_passing_prefix(x0, U) == expected
        assert [o.trajectory_ok(tr[: k + 1]) for k in range(len(tr))] == [_passes(o, tr[: k + 1]) for k in range(len(tr))]
        found += expected is not None
        if expected is not None and expected >= 2:
            late = tr
    assert 0 < found < 60  # both answers were exercised
    # leaving the state space (or touching `avoid`) on the way rules out every later step
    out = late.copy()
    out[1] = o.high + 1.0
    assert _first_passing_by_prefixes(o, out) is None and o.passing_prefix(out) is None
    if o.task.model.avoid is not None:  # attitude: the unsafe ball's centre, inside the goal
        out = late.copy()
        out[1] = prog.regions["unsafe"].centre
        assert _first_passing_by_prefixes(o, out) is None and o.passing_prefix(out) is None
    tr, _ = o.replay(low, np.zeros((4, o.m)))
    tr[2] = np.nan
    assert o.passing_prefix(tr) == _first_passing_by_prefixes(o, tr)


# A discrete double integrator that must *stay* home for three steps: historically[0, 2] in home.
DWELL = """
system Dwell {
  state p in [-50, 50] init [-8, 8]
  state v in [-50, 50] init [-2, 2]
  action u in [-1, 1]
  dt = 1
  map { p = p + v, v = v + u }
}
region home = box(p in [-0.5, 0.5], v in [-0.2, 0.2])
task settle { asap historically[0, 2] in home  deadline 25 }
"""


def _lp_minimum(x0: np.ndarray, deadline: int, margin: float = 1e-6):
    """The fewest steps N such that p, v are in home at steps N-2..N (from step 0), by a
    feasibility linear program per N (scipy's linprog) on the unrolled dynamics."""
    from scipy.optimize import linprog

    A = np.array([[1.0, 1.0], [0.0, 1.0]])
    B = np.array([[0.0], [1.0]])
    lo, hi = np.array([-0.5, -0.2]) + margin, np.array([0.5, 0.2]) - margin
    for N in range(deadline + 1):
        rows, rhs = [], []
        for k in range(N + 1):  # x_k = A^k x0 + sum_j A^(k-1-j) B u_j
            free = np.linalg.matrix_power(A, k) @ x0
            G = np.zeros((2, max(N, 1)))
            for j in range(k):
                G[:, j] = (np.linalg.matrix_power(A, k - 1 - j) @ B)[:, 0]
            bounds = [(lo, hi)] if k >= N - 2 else []
            if k >= 1:
                bounds.append((np.full(2, -50.0), np.full(2, 50.0)))
            for blo, bhi in bounds:
                rows += [G, -G]
                rhs += [bhi - free, free - blo]
        if N == 0:
            if all(np.all(r @ np.zeros(1) <= b + 1e-12) for r, b in zip(rows, rhs)):
                return 0
            continue
        res = linprog(np.zeros(N), A_ub=np.vstack(rows)[:, :N], b_ub=np.concatenate(rhs),
                      bounds=[(-1, 1)] * N, method="highs")
        if res.status == 0:
            return N
    return None


def test_a_dwell_in_a_region_is_the_minimum_a_linear_program_computes():
    prog = asap_dsl.loads(DWELL)
    oracle = O.Oracle(prog, "settle")
    assert oracle.label == "exact"
    states = np.random.default_rng(5).uniform([-8, -2], [8, 2], size=(12, 2))
    rep = O.run(prog, "settle", states=states)
    expected = [_lp_minimum(x0, 25) for x0 in states]
    assert [r.steps for r in rep.results] == expected
    assert all(r.verified for r in rep.results if r.steps is not None)
    assert max(s for s in expected if s is not None) >= 5  # the dwell costs steps: a real test


def _cli(capsys, argv):
    """``asapc oracle ARGV`` in this process: (exit status, stdout, stderr)."""
    from asap_dsl import cli

    code = cli.main(["oracle", *argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_command_json_text_and_errors(tmp_path, capsys):
    f = tmp_path / "di.asap"
    f.write_text(DOUBLE_INTEGRATOR_ODE)
    rc, out, _ = _cli(capsys, [str(f), "--episodes", "12", "--format", "json", "--task", "rest", "--states"])
    assert rc == 0
    whole = json.loads(out)
    assert set(whole) == {"file", "tasks", "skipped"} and whole["skipped"] == []  # the shape with or without --task
    d = whole["tasks"][0]
    assert d["label"] == "exact" and d["episodes"] == 12 and len(d["states"]) == 12
    rates = [row["rate"] for row in d["ceiling"]]
    assert [row["tolerance"] for row in d["ceiling"]] == [12, 6, 4] and rates == sorted(rates, reverse=True)
    for row in d["ceiling"]:
        assert row["ci95"][0] <= row["rate"] <= row["ci95"][1]
    for s in d["states"]:
        assert s["status"] in ("solved", "infeasible") and (s["steps"] is None or s["steps"] <= 12)
    rc, out, _ = _cli(capsys, [str(f), "--episodes", "5", "--format", "json"])
    assert rc == 0 and set(json.loads(out)) == {"file", "tasks", "skipped"}
    rc, out, _ = _cli(capsys, [str(f), "--episodes", "5"])
    assert rc == 0 and "oracle (exact)" in out and "tolerance" in out
    # an unknown or empty --task is a misused flag: exit 2 and the wording of every subcommand
    with pytest.raises(SystemExit) as stop:
        _cli(capsys, [str(f), "--task", "nope"])
    assert stop.value.code == 2 and "asapc: error: no task named 'nope' in" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        _cli(capsys, [str(f), "--workers", "0"])
    assert stop.value.code == 2


def test_workers_agree_with_single_process():
    prog = asap_dsl.load(SPECS / "dc_motor.asap")
    one = O.run(prog, "reach", episodes=24, workers=1)
    two = O.run(prog, "reach", episodes=24, workers=2)
    assert list(one.steps) == list(two.steps)
    assert all(r.verified for r in two.results if r.steps is not None)
    assert one.label == "exact"


@pytest.mark.parametrize("workers", [1, 2])
def test_a_search_under_a_budget_stops_taking_states_and_keeps_what_it_solved(workers):
    """The demonstrations' search: the states begun before the budget ran out, each as the
    unbounded search solves it, in input order; a budget that is not spent solves them all."""
    prog = asap_dsl.load(SPECS / "dc_motor.asap")
    full = O.run(prog, "reach", episodes=200, workers=workers)
    assert O.run(prog, "reach", episodes=200, workers=workers, budget_seconds=1e-9).results == []  # none begun
    part = O.run(prog, "reach", episodes=200, workers=workers, budget_seconds=full.seconds / 4)
    assert 0 < len(part.results) < 200
    assert [r.index for r in part.results] == sorted(r.index for r in part.results)
    by_index = {r.index: r.steps for r in full.results}
    assert all(r.steps == by_index[r.index] for r in part.results)  # linear: exact minima, whatever the order
    unspent = O.run(prog, "reach", episodes=200, workers=workers, budget_seconds=1e6)
    assert list(unspent.steps) == list(full.steps)


def test_a_wall_clock_cap_holds_while_the_workers_are_still_starting(tmp_path, monkeypatch):
    """A training run's time limit caps its demonstrations' search: spawned workers that take
    seconds to start (tens on a loaded machine, seen in CI) are given up at the cap and its grace,
    not waited for. Here every spawned worker sleeps 6 s before it starts (a ``sitecustomize`` on
    the path they inherit)."""
    pytest.importorskip("jax")  # a learner's library loaded: the pool is spawned, as in a training run
    (tmp_path / "sitecustomize.py").write_text("import time\ntime.sleep(6)\n")
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    prog = asap_dsl.load(SPECS / "dc_motor.asap")
    report = O.run(prog, "reach", episodes=200, workers=2, wall_seconds=0.5)
    assert report.results == [] and report.seconds < 0.5 + 1.0 + 3.0  # the cap, its grace, the pool's ending


def _found(report) -> list:
    return [(r.index, r.status, r.steps, None if r.actions is None else r.actions.round(9).tolist())
            for r in report.results]


def test_on_its_clock_the_search_finds_the_same_on_any_machine_and_any_workers(monkeypatch):
    """A training run's demonstrations: under a :class:`WorkClock` the time per state and the budget
    are the work the solves did, each chunk of the tour starts cold with its share of the budget, so
    one worker, two, and a machine made slow find the same states and sequences (the rover is
    non-linear: its local minima follow the warm starts)."""
    from asap_dsl.backends.oracle import solver
    from asap_dsl.backends.oracle.nlp import ShootingProblems
    from asap_dsl.sampling import task_states

    monkeypatch.setattr(solver, "BUDGET_CHUNK", 8)
    prog = asap_dsl.load(SPECS.parent / "examples" / "rover_detour.asap")
    clock = O.WorkClock()
    states = task_states(prog.system, prog.task("reach").model, 16, seed=5)
    budget = 0.5  # a quarter of the 16 states' work: both chunks stop early
    one = O.run(prog, "reach", states=states, workers=1, time_limit=5.0, budget_seconds=budget, clock=clock)
    two = O.run(prog, "reach", states=states, workers=2, time_limit=5.0, budget_seconds=budget, clock=clock)
    assert 2 <= len(one.results) < 16 and all(r.verified for r in one.results if r.status == "solved")
    assert _found(two) == _found(one)

    solve = ShootingProblems.solve

    def slow(self, *args):
        time.sleep(0.1)
        return solve(self, *args)

    monkeypatch.setattr(ShootingProblems, "solve", slow)
    slowed = O.run(prog, "reach", states=states, workers=1, time_limit=5.0, budget_seconds=budget, clock=clock)
    assert _found(slowed) == _found(one) and slowed.seconds > one.seconds
    # a run's time limit still caps the wall clock: no state begun once it is spent
    assert O.run(prog, "reach", states=states, clock=clock, budget_seconds=budget, wall_seconds=0.0).results == []


def test_on_its_clock_a_state_times_out_by_the_work_done_not_the_seconds():
    prog = asap_dsl.load(SPECS / "dc_motor.asap")
    dear = O.Oracle(prog, "reach", time_limit=5.0, clock=O.WorkClock(per_solve=10.0))  # a solve: 10 s
    x0 = O.run(prog, "reach", episodes=4).results
    far = max(x0, key=lambda r: r.steps - r.lower_bound)  # searched over more than one horizon
    r = dear.solve(far.x0)
    assert r.status == "timeout" and r.solves == 1  # one solve's work: 10 s on that clock


def test_wilson_interval():
    from asap_dsl.stats import wilson_interval

    lo, hi = wilson_interval(53, 100)
    assert lo == pytest.approx(0.4329, abs=1e-4) and hi == pytest.approx(0.6249, abs=1e-4)
    assert wilson_interval(0, 10)[0] == 0.0 and wilson_interval(10, 10)[1] == 1.0


# A double well in a `let` coordinate: from x0 = 1 (the shallow well, z = 0.3) the goal z <= -0.2
# lies in the other well (x near -1), one step away with |u| <= 3. IPOPT started from x0 held
# (the default guess) stays in the shallow well at every horizon; a bang-bang rollout finds it.
WELLS = """
system Wells {
  state x in [-10, 10] init [0.5, 1.5]
  action u in [-3, 3]
  let z = (x^2 - 1)^2 + 0.3 * x
  dt = 1
  map {
    x = x + u
  }
}
region goal = box(z in [-10, -0.2])
task reach { asap in goal  deadline 4 }
"""

# x+ = x + u + 0.1 u^3 with |u| <= 1 moves at most 1.1 per step and axis, and is not linear: the
# N-search starts at the interval bound, which is exact here (a distance of 9.5 needs 9 steps).
CUBIC = """
system Cubic {
  state x in [-10, 10] init [-5, -5]
  state y in [-10, 10] init [0, 0]
  action ux in [-1, 1]
  action uy in [-1, 1]
  dt = 1
  map {
    x = x + ux + 0.1 * ux^3
    y = y + uy + 0.1 * uy^3
  }
}
region goal = ball([5, 0], 0.5)
task reach { asap in goal  deadline 30 }
task near { asap in goal  deadline 8 }
"""


def test_multi_start_finds_what_the_single_start_misses():
    prog = asap_dsl.loads(WELLS)
    single = O.Oracle(prog, "reach", restarts=0).solve([1.0])
    assert (single.steps, single.status, single.restarts) == (None, "infeasible", 0)
    multi = O.Oracle(prog, "reach", restarts=2)
    assert multi.label == "local"
    r = multi.solve([1.0])
    assert (r.steps, r.status, r.verified) == (1, "solved", True)
    assert r.restarts >= 1 and r.solves == 1 + r.restarts
    assert prog.regions["goal"].satisfied(r.trajectory[-1:]).all()
    again = O.Oracle(prog, "reach", restarts=2).solve([1.0])  # deterministic
    assert (again.steps, again.solves, again.restarts) == (r.steps, r.solves, r.restarts)
    np.testing.assert_array_equal(again.actions, r.actions)
    # linear dynamics do not restart by default (convex, or non-convex only in avoid / the goal)
    assert O.Oracle(asap_dsl.loads(PLANE), "reach").restarts == 0


def test_interval_lower_bound_is_sound_and_tight():
    prog = asap_dsl.loads(CUBIC)
    o = O.Oracle(prog, "reach")
    assert not o.linear and o.label == "local"
    assert o.lower_bound(np.array([-5.0, 0.0])) == 9
    r = o.solve([-5.0, 0.0])
    assert (r.steps, r.lower_bound, r.verified) == (9, 9, True)
    assert O.Oracle(prog, "reach", interval_bound=False).lower_bound(np.array([-5.0, 0.0])) == 0
    # unreachable within the deadline: proved by the bound, no NLP solved
    far = O.Oracle(prog, "near").solve([-5.0, 0.0])
    assert (far.steps, far.status, far.solves) == (None, "infeasible", 0)
    # the bicycle: the bound never exceeds the minimum the local search verifies
    bike = asap_dsl.load(SPECS / "bicycle.asap")
    ob = O.Oracle(bike, "reach")
    for x0 in ([-1.5, -1.5, 0.0, 0.0], [0.0, 0.0, 0.3, 1.0], [-1.0, 0.5, 0.2, 1.0]):
        lb = ob.lower_bound(np.asarray(x0))
        res = ob.solve(x0)
        assert res.steps is None or lb <= res.steps
        assert res.steps is None or res.verified


def test_tighten_takes_the_min_and_every_sequence_replays():
    prog = asap_dsl.loads(PLANE)
    states = np.array([[-5.0, 0.0], [-4.0, 1.0], [-6.0, -0.5], [3.0, 0.5]])
    free = O.run(prog, "reach", states=states)
    avoid = O.run(prog, "reach_avoid", states=states)
    # a worse local search for `reach`: state 0 "infeasible"; state 1 one step longer than
    # with the obstacle (zero actions first keep the point where it is: still a valid sequence)
    r0, r1 = free.results[0], free.results[1]
    assert avoid.steps[0] > r0.steps  # the disc is in the way of state 0
    free.results[0] = O.StateResult(0, r0.x0, None, "infeasible", False)
    k = int(avoid.steps[1]) - r1.steps + 1
    free.results[1] = O.StateResult(1, r1.x0, r1.steps + k, "solved", True,
                                    actions=np.vstack([np.zeros((k, 2)), r1.actions]))
    # a bogus `reach_avoid` answer for state 2 (claims 1 step): must not be adopted
    ra2, r2 = avoid.results[2], free.results[2]
    avoid.results[2] = O.StateResult(2, ra2.x0, 1, "solved", True, actions=np.zeros((1, 2)))
    got = O.tighten(prog, [free, avoid])
    assert got == {"reach": 2, "reach_avoid": 0}
    assert free.extra["tightened"] == {"from": ["reach_avoid"], "improved_states": 2}
    assert free.steps[0] == avoid.steps[0] and free.steps[1] <= avoid.steps[1]
    assert free.results[2] is r2 and free.results[3].steps == 0 or free.results[3].source is None
    checker = {"reach": O.Oracle(prog, "reach"), "reach_avoid": O.Oracle(prog, "reach_avoid")}
    for rep in (free, avoid):
        for r in rep.results:
            if r.steps is None or (rep is avoid and r.index == 2):
                continue
            tr, ok = checker[rep.task].replay(r.x0, r.actions)
            assert ok and len(r.actions) == r.steps, (rep.task, r.index)
            assert r.verified
    assert free.results[0].source == "reach_avoid" and free.results[2].source is None


def test_progress_is_reported_as_states_finish_and_shown_on_a_terminal():
    from asap_dsl.cli.progress import StatesProgress

    prog = asap_dsl.load(SPECS / "dc_motor.asap")
    for workers in (1, 2):
        seen = []
        O.run(prog, "reach", episodes=20, workers=workers, progress=seen.append)
        assert sum(seen) == 20 and len(seen) > 1

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    screen = Terminal()
    bar = StatesProgress(screen, "reach", 20)
    bar(5)
    bar(5)
    assert "10/20 states" in screen.getvalue() and "left" in screen.getvalue()
    quiet = io.StringIO()
    StatesProgress(quiet, "reach", 20)(5)
    assert quiet.getvalue() == ""  # nothing in a pipe or a log


def test_an_unsupported_task_does_not_stop_the_others(tmp_path, capsys):
    f = tmp_path / "mixed.asap"
    f.write_text(PLANE + "task with_since { asap in goal since x > 0  deadline 30 }\n")
    rc, out, err = _cli(capsys, [str(f), "--episodes", "3", "--format", "json", "--workers", "1"])
    d = json.loads(out)
    assert rc == 0 and "with_since" in err and "`since`" in err
    assert [s["task"] for s in d["skipped"]] == ["with_since"]
    assert {t["task"] for t in d["tasks"]} == {"reach", "reach_avoid", "far", "cmp", "temporal", "either"}


def test_the_default_is_one_worker_per_core():
    import argparse

    from asap_dsl.cli import available_cores

    p = argparse.ArgumentParser()
    add_oracle_arguments(p)
    assert p.parse_args(["x.asap"]).workers is None  # resolved to available_cores() when run
    assert available_cores() >= 1


def test_affine_probe_reads_an_affine_map_with_and_without_actions():
    from asap_dsl.dynamics import affine_probe

    A0, B0, c0 = np.array([[1.0, 2.0], [0.0, -1.0], [3.0, 0.5]]), np.array([[1.0], [0.0], [-2.0]]), np.array([0.5, 0.0, 1.0])
    A, B, c = affine_probe(lambda x, u: x @ A0.T + u @ B0.T + c0, 2, 1)
    assert np.allclose(A, A0) and np.allclose(B, B0) and np.allclose(c, c0)
    A, B, c = affine_probe(lambda x, u: x @ A0.T + c0, 2, 0)  # no actions: B is [k, 0]
    assert np.allclose(A, A0) and B.shape == (3, 0) and np.allclose(c, c0)


def test_the_normal_form_is_typed_records():
    from asap_dsl.backends.oracle.goals import AllOf, AnyOf, Constant, Literal, dnf, normal

    prog = asap_dsl.loads(DOUBLE_INTEGRATOR_MAP.replace("asap in goal", "asap historically[0, 2] in goal"))
    f = normal(prog.task("reach").model.asap, 5)
    assert isinstance(f, AllOf) and [(g.positive, g.back) for g in f.parts] == [(True, 0), (True, 1), (True, 2)]
    assert all(isinstance(g, Literal) and g.atom.region == "goal" for g in f.parts)
    assert isinstance(normal(prog.task("reach").model.asap, 1), AllOf)  # the window cut at step 0
    neg = normal(prog.task("reach").model.asap, 5, positive=False)  # not historically: once not
    assert isinstance(neg, AnyOf) and len(dnf(neg)) == 3 and not any(lit.positive for c in dnf(neg) for lit in c)
    assert dnf(Constant(True)) == [[]] and dnf(Constant(False)) == []


GEAR = """\
system Gear {
  state x in [-5, 5] init [-3, -3]
  action u in [-1, 1]
  let gear = if x < 0 then 2 else 1      # a let of states in the map, switching on the way
  map { x = clip(x + gear * u, -5, 5) }
}
task up { asap x >= 2  deadline 10 }
"""


@pytest.mark.parametrize("x0, steps", [(-3.0, 3), (-4.5, 4), (-0.5, 2), (0.5, 2), (4.9, 0)])
def test_oracle_through_a_conditional_and_clip(x0, steps):
    """The NLP sees if_else and fmin/fmax (non-smooth): the minimum times are still found here,
    where the switch is crossed once on the way (-3 -> -1 -> 1 -> 2 takes 3 steps, not 5)."""
    r = O.Oracle(asap_dsl.loads(GEAR), "up", time_limit=10.0).solve([x0])
    assert r.status == "solved" and r.verified and r.steps == steps


def test_an_interrupted_search_resumes_where_it_stopped(tmp_path, monkeypatch):
    """The ceiling of 1000 attitude states takes 20 minutes: a Ctrl-C (or a killed sweep) used to
    lose all of it. Each finished chunk is kept now, and the next search of the same states
    begins with them; the cache entry replaces the partial file."""
    from conftest import RAIL

    monkeypatch.setenv("ASAP_CACHE_DIR", str(tmp_path / "cache"))
    prog = asap_dsl.loads(RAIL)
    seen: list[int] = []

    def interrupt_at_the_22nd_state(k: int) -> None:
        seen.append(k)
        if sum(seen) >= 22:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):  # 8 chunks of 5 states: 4 ended, the 5th cut
        O.solve_seeded(prog, "go", 2024, 40, workers=1, progress=interrupt_at_the_22nd_state)
    partial = O.cache_path(prog.source, "go", 2024, 40).with_suffix(".partial.json")
    kept = json.loads(partial.read_text())
    assert len(kept["results"]) == 20
    told: list[int] = []
    resumed = O.solve_seeded(prog, "go", 2024, 40, workers=1, progress=told.append)
    assert told[0] == 20 and sum(told) == 40  # 20 kept, 20 solved
    fresh = O.run(prog, "go", episodes=40, workers=1)
    np.testing.assert_array_equal(resumed.steps, fresh.steps)
    assert [r.index for r in resumed.results] == list(range(40))
    assert all(r.trajectory is not None for r in resumed.results if r.actions is not None)
    O.store(prog.source, resumed)
    assert not partial.exists() and O.load(prog.source, "go", 2024, 40) is not None
    # what a search with another time limit kept is not used
    partial.write_text(json.dumps({**kept, "time_limit": 1.0}))
    told.clear()
    O.solve_seeded(prog, "go", 2024, 40, workers=1, progress=told.append)
    assert told == [1] * 40


def test_state_results_serialise_numpy_numbers():
    """The solver hands numpy integers and booleans (a state's index from an index array, a step
    count from an argmin): `asapc oracle --format json --states` must still write plain JSON."""
    from asap_dsl.backends.oracle.planner import PlannedState

    acts = np.zeros((3, 1))
    solved = O.StateResult(np.int64(4), np.array([0.1, 0.2]), np.int64(3), "solved", np.bool_(True),
                           np.int64(0), np.int64(2), np.int64(1), acts, None, 0.5, np.int64(1), None, np.int64(3))
    planned = PlannedState(np.int64(2), np.array([0.0]), np.int64(7), "solved", np.bool_(True), actions=acts,
                           rollouts=np.int64(128), iterations=np.int64(60))
    for r in (solved, planned):
        d = json.loads(json.dumps(r.to_dict(with_actions=True)))
        assert d["index"] == int(r.index) and d["steps"] == int(r.steps) and d["verified"] is True
        assert type(r).from_dict(d).to_dict(with_actions=True) == d  # what the cache reads back
