"""Environments: episode rules, end reasons, determinism, env checker, the batched vector env."""

import warnings
from pathlib import Path

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import asap_dsl
from asap_dsl.stl import ir

SPECS = Path(__file__).resolve().parent.parent / "specs"
BENCH = [(p.stem, t) for p in sorted(SPECS.glob("*.asap")) for t in ("reach", "reach_avoid")]

LINE = """
system Line {
  state x in [-10, 10] init [-1, 1]
  state y in [-10, 10] init [-1, 1]
  action u in [-1, 1]
  action g in [-1, 1]
  dt = 1
  map { x = x + u
        y = y * 1e200 ^ (g + 1) }
}
region goal   = ball([5, 0], 1)
region unsafe = box(x in [2, 3], y in [-1, 1])
task reach { asap in goal  deadline 12  episode 5..9 }
task ra { asap in goal  avoid in unsafe  deadline 12  episode 5..9  observe state, time  reward rho }
task past { asap historically[0, 2] in goal  avoid once[0, 1] in unsafe  deadline 12  episode 4..8
            reward rho(window = 3) }
"""


@pytest.fixture(scope="module")
def line():
    return asap_dsl.loads(LINE, "line.asap")


@pytest.mark.parametrize("spec, task", BENCH)
def test_env_checker_passes(spec, task):
    env = asap_dsl.make_env(SPECS / f"{spec}.asap", task=task, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env, skip_render_check=True)


def _run(env, actions, seed):
    obs, info = env.reset(seed=seed)
    out = [obs]
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        out.append(obs)
        assert np.isfinite(obs).all() and env.observation_space.contains(obs)
        if term or trunc:
            return out, info
    return out, info


def test_end_reasons_all_reachable(line):
    env = asap_dsl.make_env(line, task="ra", seed=0)
    obs, info = env.reset(seed=5)
    c = env.unwrapped.core
    # avoid: walk right into the box x in [2, 3]
    _, info = _run(env, [[1.0, -1.0]] * 12, seed=5)
    assert info["end_reason"] == "avoid"
    # out of bounds: walk left out of x >= -10 (episodes 5..9 steps are too short: stretch k)
    env.reset(seed=6)
    c.k[:] = 100
    for _ in range(30):
        obs, r, term, trunc, info = env.step([-1.0, -1.0])
        if term or trunc:
            break
    assert term and info["end_reason"] == "out_of_bounds"
    # non-finite: y * 1e200^2 overflows to inf after a few steps (y starts non-zero)
    env.reset(seed=7)
    for _ in range(10):
        obs, r, term, trunc, info = env.step([0.0, 1.0])
        if term or trunc:
            break
    assert term and info["end_reason"] in ("non_finite", "out_of_bounds")
    c.states[:] = [[0.0, 0.5]]
    c.sim.reset(c.states)
    c.k[:] = 100
    obs, r, term, trunc, info = env.step([0.0, 1.0])  # 0.5 * 1e400 = inf
    assert term and info["end_reason"] == "non_finite"
    assert np.isfinite(obs).all() and np.isfinite(r)
    assert np.allclose(obs[:2], [0.0, 0.5])  # the last finite state is observed
    # time limit: stand still; the episode length is within 5..9
    lengths = set()
    for s in range(20):
        env.reset(seed=100 + s)
        for n in range(1, 20):
            obs, r, term, trunc, info = env.step([0.0, -1.0])
            if term or trunc:
                break
        assert trunc and not term and info["end_reason"] == "time_limit"
        lengths.add(n)
    assert lengths <= set(range(5, 10)) and len(lengths) > 2


def test_reaching_does_not_end_and_t_reach(line):
    env = asap_dsl.make_env(line, task="reach", seed=0)
    obs, info = env.reset(seed=1)
    c = env.unwrapped.core
    c.states[:] = [[3.5, 0.0]]
    c.sim.reset(c.states)
    c.k[:] = 8
    rs = []
    for i in range(8):
        obs, r, term, trunc, info = env.step([1.0 if i == 0 else 0.0, -1.0])
        rs.append(r)
        assert not term
        if i < 7:
            assert not trunc
    assert info["t_reach"] == 1 and info["satisfied"] and info["end_reason"] == "time_limit"
    assert all(r == pytest.approx(c.tm.r_sat_value) for r in rs)


def test_time_observation(line):
    env = asap_dsl.make_env(line, task="ra", seed=0)
    obs, _ = env.reset(seed=3)
    k = int(env.unwrapped.core.k[0])
    assert obs.shape == (3,) and obs[2] == pytest.approx(k / 12)
    obs, *_ = env.step([0.0, -1.0])
    assert obs[2] == pytest.approx((k - 1) / 12)


def test_same_seed_same_rollout():
    for spec in ("attitude", "swimmer"):
        env = asap_dsl.make_env(SPECS / f"{spec}.asap", task="reach_avoid")
        acts = np.random.default_rng(0).uniform(env.action_space.low, env.action_space.high, (20, env.action_space.shape[0]))
        a, ia = _run(env, acts, seed=11)
        b, ib = _run(env, acts, seed=11)
        c, _ = _run(env, acts, seed=12)
        assert np.array_equal(np.array(a), np.array(b)) and ia == ib
        assert not np.array_equal(a[0], c[0])
    v1 = asap_dsl.make_vec_env(SPECS / "dc_motor.asap", "reach", num_envs=8, seed=4)
    v2 = asap_dsl.make_vec_env(SPECS / "dc_motor.asap", "reach", num_envs=8, seed=4)
    o1, o2 = v1.reset(), v2.reset()
    assert np.array_equal(o1, o2)
    for _ in range(40):
        a = np.full((8, 1), 20.0)
        s1, s2 = v1.step(a), v2.step(a)
        assert np.array_equal(s1[0], s2[0]) and np.array_equal(s1[1], s2[1])


def test_diverging_attitude_ends_cleanly():
    text = (SPECS / "attitude.asap").read_text()
    for w in ("w1", "w2", "w3"):
        text = text.replace(f"state {w} in [-4, 4]", f"state {w} in [-1e150, 1e150]")
    for p in ("p1", "p2", "p3"):
        text = text.replace(f"state {p} in [-2, 2]", f"state {p} in [-1e150, 1e150]")
    prog = asap_dsl.loads(text, "attitude_wide.asap")
    for spec_prog, reasons in ((asap_dsl.load(SPECS / "attitude.asap"), {"out_of_bounds"}),
                               (prog, {"non_finite", "out_of_bounds"})):
        env = asap_dsl.make_env(spec_prog, task="reach_avoid", seed=0)
        env.reset(seed=0)
        c = env.unwrapped.core
        c.states[:] = [[0.7, -0.7, 0.7, 0.9, -0.9, 0.9]]
        c.sim.reset(c.states)
        c.k[:] = 10_000
        for u in ([5.0, -5.0, 5.0], [0.0, 0.0, 0.0]):
            env.reset(seed=0)
            c.states[:] = [[0.7, -0.7, 0.7, 0.9, -0.9, 0.9]]
            c.sim.reset(c.states)
            c.k[:] = 10_000
            for _ in range(500):
                obs, r, term, trunc, info = env.step(u)
                assert np.isfinite(obs).all() and np.isfinite(r)
                if term or trunc:
                    break
            assert term and info["end_reason"] in reasons, info


def _vec_rollout(venv, steps, rng):
    """Per entry: list of episodes, each a list of (state, reward) with the true states."""
    c = venv.core
    venv.reset()
    episodes = [[[(c.states[i].copy(), None)]] for i in range(venv.num_envs)]
    ends = []
    for _ in range(steps):
        a = rng.uniform(venv.action_space.low, venv.action_space.high, (venv.num_envs, venv.action_space.shape[0]))
        a[:, 0] = 0.3 + 0.7 * a[:, 0]  # drift right, towards the box and the goal
        a[:, 1] = -1.0  # keep y (g = -1)
        obs, r, done, infos = venv.step(a)
        finals = iter(c.final_states) if done.any() else None
        for i in range(venv.num_envs):
            if done[i]:
                assert "terminal_observation" in infos[i]
                term = next(finals)
                episodes[i][-1].append((term, r[i]))
                ends.append(infos[i]["end_reason"])
                episodes[i][-1].append(infos[i]["end_reason"])
                assert np.allclose(obs[i][: c.n], c.states[i])
                episodes[i].append([(c.states[i].copy(), None)])
            else:
                episodes[i][-1].append((c.states[i].copy(), r[i]))
    return episodes, ends


@pytest.mark.parametrize("task, reward", [("ra", "rho"), ("past", None), ("ra", "rho(window = 4)")])
def test_vec_env_rewards_match_offline_across_autoresets(line, task, reward):
    venv = asap_dsl.make_vec_env(line, task, num_envs=6, seed=0, reward=reward)
    episodes, ends = _vec_rollout(venv, 60, np.random.default_rng(0))
    t = line.task(task).model
    if reward is None or reward == "rho(window = 4)":
        W = 4 if reward else 3
        node = ir.Once(ir.Interval(0, W - 1), t.asap)
        node = ir.And(node, ir.Historically(ir.Interval(0, W - 1), ir.Not(t.avoid)))
        formula = asap_dsl.Formula(node, 2)
        value = lambda tr: formula.robustness(tr)[-1]  # noqa: E731
    else:
        spec = line.task(task).spec
        value = lambda tr: spec.robustness(tr)[0]  # noqa: E731
    lo, hi = asap_dsl.Formula(node if reward != "rho" else t.spec, 2).bounds
    checked = 0
    for per_entry in episodes:
        for ep in per_entry:
            reason = ep.pop() if isinstance(ep[-1], str) else None
            trace = np.array([s for s, _ in ep], dtype=float)
            for j in range(1, len(ep)):
                r = ep[j][1]
                if j == len(ep) - 1 and reason in ("avoid", "out_of_bounds", "non_finite"):
                    assert r == pytest.approx(lo)  # a failure step earns the floor
                    continue
                assert r == pytest.approx(np.clip(value(trace[: j + 1]), lo, hi), abs=1e-5), (j, trace)
                checked += 1
    assert checked > 200 and len(ends) > 20
    lengths = {len(ep) - 1 for per in episodes for ep in per[:-1]}
    assert {"time_limit", "avoid"} <= set(ends) or task == "past"
    assert len(lengths) > 1  # per-entry episode lengths


def test_vec_env_asap_and_end_reasons(line):
    venv = asap_dsl.make_vec_env(line, "ra", num_envs=32, seed=1, reward="asap")
    episodes, ends = _vec_rollout(venv, 40, np.random.default_rng(1))
    assert {"avoid", "time_limit"} <= set(ends)


def test_sb3_sac_learns_on_vec_env():
    from stable_baselines3 import SAC

    venv = asap_dsl.make_vec_env(SPECS / "dc_motor.asap", "reach_avoid", num_envs=4, seed=0)
    model = SAC("MlpPolicy", venv, learning_starts=50, batch_size=32, train_freq=1, seed=0, verbose=0,
                policy_kwargs={"net_arch": [32, 32]})
    model.learn(300)
    assert model.num_timesteps >= 300
    obs = venv.reset()
    act, _ = model.predict(obs, deterministic=True)
    assert act.shape == (4, 1)


def test_gymnasium_ids():
    import gymnasium

    env = gymnasium.make("asap/dc_motor-reach_avoid-v0")
    obs, info = env.reset(seed=0)
    assert obs.shape == (3,) and info["end_reason"] is None
    env = gymnasium.make("asap/swimmer-reach-v0")
    assert env.reset(seed=0)[0].shape == (10,)


def test_fractional_env_counts_and_non_finite_failure_rewards_are_refused():
    prog = asap_dsl.load(SPECS / "dc_motor.asap")
    for bad in (2.5, 0, True):
        with pytest.raises(ValueError, match="num_envs"):
            asap_dsl.make_vec_env(prog, "reach", num_envs=bad)
    with pytest.raises(ValueError, match="failure_reward"):
        asap_dsl.make_env(prog, "reach", failure_reward=float("nan"))


def test_windows_longer_than_any_episode_cost_no_memory():
    """`once[0, 1e8]` with a deadline of 30 steps: the monitor holds an episode, not 1e8 steps."""
    import tracemalloc

    text = (SPECS / "dc_motor.asap").read_text().replace(
        "task reach {\n  asap       in goal", "task reach {\n  asap       once[0, 100000000] in goal", 1)
    text = text.replace("task reach_avoid {\n  asap       in goal\n  avoid      in unsafe",
                        "task reach_avoid {\n  asap       in goal\n  avoid      historically[0, 100000000] in unsafe\n"
                        "  reward     rho(window = 100000000)", 1)
    prog = asap_dsl.loads(text, "dc_motor.asap")
    tracemalloc.start()
    for task in ("reach", "reach_avoid"):
        venv = asap_dsl.make_vec_env(prog, task, num_envs=16, seed=0)
        venv.reset()
        for _ in range(40):
            _, r, _, _ = venv.step_arrays(np.zeros((16, 1)))
            assert np.isfinite(r).all()
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 50e6, peak


def test_capping_past_windows_is_exact_on_episode_length_traces():
    from asap_dsl.stl import ir, offline

    prog = asap_dsl.load(SPECS / "dc_motor.asap")
    goal = prog.task("reach").model.asap
    formulas = [ir.Once(ir.Interval(0, 10**8), goal), ir.Historically(ir.Interval(2, 10**8), ir.Not(goal)),
                ir.Once(ir.Interval(40, 50), goal), ir.Since(ir.Interval(1, 10**7), ir.Not(goal), goal),
                ir.Historically(ir.Interval(0, 5), ir.Once(ir.Interval(3, 10**6), goal))]
    rng = np.random.default_rng(1)
    traces = rng.uniform([0.5, -2, -2], [2.5, 2, 2], size=(64, 31, 3))
    for f in formulas:
        capped = ir.cap_past_windows(f, 30)
        assert np.array_equal(offline.robustness(f, traces, n_state=3), offline.robustness(capped, traces, n_state=3))
        assert np.array_equal(offline.satisfied(f, traces, n_state=3), offline.satisfied(capped, traces, n_state=3))


def test_reset_info_is_finite_where_rho_is_infinite():
    """At step 0 a past window that starts later is empty: rho is -inf (once) or +inf
    (historically) there. The info of a reset makes it finite as a step's does (the formula's
    bound), in the single and the vector env alike."""
    src = ("system A { state x in [-1, 1] init [-0.5, 0.5]  action u in [-1, 1]  dt = 1  map { x = x + 0.1 * u } }\n"
           "task low { asap once[1, 2] x > 0.5  deadline 5 }\n"
           "task high { asap historically[1, 2] x > 0.5  deadline 5 }")
    prog = asap_dsl.loads(src)
    for task, expected in (("low", -np.inf), ("high", np.inf)):
        env = asap_dsl.make_env(prog, task=task, seed=0)
        _, info = env.reset(seed=0)
        assert env.unwrapped.core.asap.rob[0] == expected  # what the monitor says: infinite
        lo, hi = prog.task(task).model.rho_bounds
        assert np.isfinite(info["rho"]) and info["rho"] == (lo if expected < 0 else hi), info
        venv = asap_dsl.make_vec_env(prog, task=task, num_envs=3, seed=0)
        venv.reset()
        assert all(np.isfinite(i["rho"]) for i in venv.reset_infos), venv.reset_infos
        assert [i["end_reason"] for i in venv.reset_infos] == [None] * 3 and [i["t"] for i in venv.reset_infos] == [0] * 3


def test_bounds_at_zero_and_beyond_float32_make_no_warning():
    """A state bounded at 0 (a forward-only speed) and one beyond float32's range: the
    observation space is built without a NumPy warning reaching the user, and is right."""
    spec = """
system Rover {
  state v in [0, 2] init [0, 1]
  state w in [-1e300, 0] init [-1, 0]
  action a in [-1, 1]
  dt = 0.1
  ode { v' = a
        w' = a }
}
task t { asap v > 1.5  deadline 10 }
"""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = asap_dsl.make_env(asap_dsl.loads(spec, "zero.asap"), seed=0)
    assert env.observation_space.low.tolist() == [0.0, -np.inf]
    assert env.observation_space.high.tolist() == [2.0, 0.0]
