"""The compiled step (asap_dsl.native) against the numpy step: the same episodes, values and infos.

Both vector envs get the same seed and the same actions (some beyond the action bounds) and run
whole episodes with autoresets; at every step observations, rewards, terminated/truncated/done,
every info (rho, satisfied, t_reach, end_reason, t, terminal_observation, TimeLimit.truncated),
the states, t, k and t_reach must agree: to the bit where the operations are the same (every
spec without numpy's SIMD functions or a matrix product), else states to 1e-12 relative.
Machine code is cached across sessions in pytest's temporary root (not the user's cache).
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import asap_dsl
from asap_dsl.env import EnvCore, infos, make_env, make_vec_env
from asap_dsl.native import resolve_engine, with_engine
from asap_dsl.native.core import NativeCore
from asap_dsl.stl import offline
from conftest import ROOT, fuzz_examples
from test_env import LINE

SPECS, EXAMPLES = ROOT / "specs", ROOT / "examples"
#: Specs whose operations are numpy's to the bit (no tan/atan/exp/... nor a matrix exponential).
EXACT = {"attitude", "swimmer"}


@pytest.fixture(autouse=True)
def _native_cache(_private_cache, tmp_path_factory, monkeypatch):
    monkeypatch.setenv("ASAP_CACHE_DIR", str(tmp_path_factory.getbasetemp().parent / "asap-native-cache"))


def _pair(prog, task, n, reward=None, seed=0):
    a = make_vec_env(prog, task, num_envs=n, seed=seed, reward=reward, engine="numpy")
    b = make_vec_env(prog, task, num_envs=n, seed=seed, reward=reward, engine="native")
    assert isinstance(b.core, NativeCore) and not isinstance(a.core, NativeCore)
    return a, b


def _same(x, y, exact: bool, what: str, rtol: float = 1e-12, scale=None):
    x, y = np.asarray(x), np.asarray(y)
    assert x.shape == y.shape and x.dtype == y.dtype, (what, x, y)
    if exact or x.dtype.kind not in "f":
        assert np.array_equal(x, y, equal_nan=True), (what, x, y)
        return
    tol = rtol * (np.abs(x) + (1.0 if scale is None else scale))
    assert np.all(np.abs(x - y) <= tol), (what, x, y)


def _same_infos(ia, ib, exact: bool):
    assert len(ia) == len(ib)
    for p, q in zip(ia, ib):
        assert p.keys() == q.keys(), (p, q)
        for key in p:
            if key == "terminal_observation":
                _same(p[key], q[key], exact, key, rtol=1e-6)
            elif key == "rho" and not exact:
                assert math.isclose(p[key], q[key], rel_tol=1e-9, abs_tol=1e-9), (p, q)
            else:
                assert p[key] == q[key] and type(p[key]) is type(q[key]), (key, p, q)


def agree(prog, task, n=4, steps=120, reward=None, seed=0, exact=True, action_seed=1):
    """Run both engines side by side; returns the number of episodes that ended."""
    a, b = _pair(prog, task, n, reward, seed)
    oa, ob = a.reset(), b.reset()
    _same(oa, ob, exact, "reset obs", rtol=1e-6)
    _same_infos(a.reset_infos, b.reset_infos, exact)
    rng = np.random.default_rng(action_seed)
    lo, hi = a.action_space.low, a.action_space.high
    width = np.where(np.isfinite(hi - lo), hi - lo, 2.0)
    scale = np.where(np.isfinite(a.core.high - a.core.low), np.abs(a.core.high - a.core.low), 1.0)
    ended = 0
    for step in range(steps):
        act = rng.uniform(lo - 0.1 * width, hi + 0.1 * width, size=(n, lo.shape[0]))
        act = act.astype(np.float32) if step % 2 else act  # both dtypes SB3 and users pass
        a.step_async(act)
        b.step_async(act)
        oa, ra, da, ia = a.step_wait()
        ob, rb, db, ib = b.step_wait()
        _same(oa, ob, exact, f"obs at {step}", rtol=1e-6)
        _same(ra, rb, exact, f"reward at {step}", rtol=1e-6)
        _same(da, db, True, f"done at {step}")
        _same_infos(ia, ib, exact)
        for name in ("t", "k", "t_reach", "end"):
            _same(getattr(a.core, name), getattr(b.core, name), True, name)
        _same(a.core.states, b.core.states, exact, f"states at {step}", scale=scale)
        ended += int(da.sum())
    assert a.core.rng.bit_generator.state == b.core.rng.bit_generator.state
    return ended


BENCH = [(SPECS / f"{s}.asap", t) for s in ("attitude", "bicycle", "dc_motor") for t in ("reach", "reach_avoid")]


@pytest.mark.parametrize("path, task", BENCH + [(EXAMPLES / "double_integrator.asap", "park")],
                         ids=lambda v: getattr(v, "stem", v))
@pytest.mark.parametrize("n", [1, 5])
def test_benchmark_specs_agree_over_episodes_with_autoresets(path, task, n):
    ended = agree(asap_dsl.load(path), task, n=n, steps=150, exact=path.stem in EXACT)
    assert ended >= n  # the episodes did end and restart


@pytest.mark.parametrize("reward", ["rho", "rho(window = 4)", "distance(lambda_t = 2, lambda_o = 0.5, base = 1)",
                                    "asap"])
@pytest.mark.parametrize("path, task", [(SPECS / "attitude.asap", "reach_avoid"),
                                        (EXAMPLES / "double_integrator.asap", "park")],
                         ids=lambda v: getattr(v, "stem", v))
def test_every_reward_agrees(path, task, reward):
    agree(asap_dsl.load(path), task, n=3, steps=100, reward=reward, exact=path.stem in EXACT)


def test_lets_of_actions_clip_and_conditionals_agree_exactly():
    # The mountain car: lets reading the action, clip, and the wall's `if`; started at the wall
    # too, moving left, so that the conditional's both branches are taken.
    text = (EXAMPLES / "mountain_car.asap").read_text()
    assert agree(asap_dsl.loads(text, "mountain_car.asap"), "reach", n=4, steps=210) >= 4
    wall = text.replace("init [-0.6, -0.4]", "init [-1.2, -1.15]").replace("init [0, 0]", "init [-0.07, 0]")
    prog = asap_dsl.loads(wall, "wall.asap")
    assert agree(prog, "reach", n=4, steps=40) == 0
    for engine in ("numpy", "native"):
        env = make_vec_env(prog, "reach", num_envs=2, seed=0, engine=engine)
        env.reset()
        env.core.states[:] = [[-1.19, -0.07], [-1.19, 0.01]]
        if engine == "numpy":
            env.core.sim.reset(env.core.states.copy())
        env.step_arrays(np.full((2, 1), -1.0))
        assert env.core.states[0].tolist() == [-1.2, 0.0]  # stopped at the wall
        assert env.core.states[1, 1] > 0.0


def test_black_box_simulator_keeps_its_stepping_with_the_rest_compiled():
    prog = asap_dsl.load(SPECS / "swimmer.asap")
    for reward in (None, "rho"):
        assert agree(prog, "reach_avoid", n=2, steps=60, reward=reward) >= 1


def test_failure_reward_and_non_finite_states():
    prog = asap_dsl.loads(LINE, "line.asap")  # 1e200 ^ (g + 1): numpy's SIMD power, not the C library's
    for task in ("reach", "ra", "past"):
        agree(prog, task, n=3, steps=80, exact=False)
    agree(prog, "ra", n=2, steps=60, reward="rho", exact=False)
    env_a = make_vec_env(prog, "reach", num_envs=2, seed=3, engine="numpy", failure_reward=-7.0)
    env_b = make_vec_env(prog, "reach", num_envs=2, seed=3, engine="native", failure_reward=-7.0)
    env_a.reset(), env_b.reset()
    for _ in range(30):  # y * 1e200^(g + 1) overflows: non_finite episodes earn the failure reward
        act = np.array([[0.0, 1.0], [1.0, 1.0]])
        ra, rb = env_a.step(act), env_b.step(act)
        for x, y in zip(ra[:3], rb[:3]):
            assert np.allclose(x, y, rtol=1e-6)
        _same_infos(ra[3], rb[3], False)




# ---- fuzzed specs -------------------------------------------------------------------------------
# Only operations numpy computes as numba does (sin, cos, sqrt, abs, min, max, norm, clip, powers 2
# and 0.5, conditionals): the agreement must then be exact, every decision included.

def _expr(draw, names, depth=0):
    if depth > 2 or draw(st.booleans()):
        return draw(st.sampled_from(names + ["0.5", "1", "2", "pi"]))
    kind = draw(st.sampled_from(["bin", "bin", "fn", "pow", "neg", "var", "clip", "if"]))
    a = _expr(draw, names, depth + 1)
    if kind == "clip":
        return f"clip({a}, {_expr(draw, names, depth + 1)}, {_expr(draw, names, depth + 1)})"
    if kind == "if":
        b, c = _expr(draw, names, depth + 1), _expr(draw, names, depth + 1)
        op = draw(st.sampled_from(["<", "<=", ">", ">=", "==", "!="]))
        join = draw(st.sampled_from(["", f" and not ({b} < 0)", f" or {a} > 1"]))
        return f"(if {a} {op} {b}{join} then {b} else {c})"
    if kind == "neg":
        return f"-({a})"
    if kind == "pow":
        return f"({a})^{draw(st.sampled_from(['2', '0.5']))}"
    if kind == "fn":
        fn = draw(st.sampled_from(["sin", "cos", "abs", "sqrt", "min", "max", "norm"]))
        if fn in ("min", "max", "norm"):
            return f"{fn}({a}, {_expr(draw, names, depth + 1)})"
        return f"{fn}({a})"
    b = _expr(draw, names, depth + 1)
    return f"({a} {draw(st.sampled_from(['+', '-', '*', '/']))} {b})"


def _interval(draw):
    lo = draw(st.integers(0, 3))
    hi = draw(st.one_of(st.integers(lo, lo + 5).map(str), st.just("inf")))
    return f"[{lo}, {hi}]"


def _formula(draw, atoms, depth=0):
    if depth > 2 or draw(st.booleans()):
        return draw(st.sampled_from(atoms))
    kind = draw(st.sampled_from(["not", "and", "or", "implies", "H", "O", "S", "true"]))
    a = _formula(draw, atoms, depth + 1)
    if kind == "true":
        return draw(st.sampled_from(["true", "false"]))
    if kind == "not":
        return f"not ({a})"
    if kind in ("H", "O"):
        return f"{'historically' if kind == 'H' else 'once'}{_interval(draw)} ({a})"
    b = _formula(draw, atoms, depth + 1)
    if kind == "S":
        return f"({a}) since{_interval(draw)} ({b})"
    return f"({a}) {'->' if kind == 'implies' else kind} ({b})"


@st.composite
def specs(draw):
    n, m = draw(st.integers(1, 3)), draw(st.integers(1, 2))
    xs, us = [f"x{i}" for i in range(n)], [f"u{j}" for j in range(m)]
    kind = draw(st.sampled_from(["rk4", "euler", "map"]))
    lines = ["system Fuzz {"]
    lines += [f"  state {x} in [-4, 4] init [-1.5, 1.5]" for x in xs]
    lines += [f"  action {u} in [-1, 1]" for u in us]
    lines.append(f"  let s = {_expr(draw, xs)}")
    lines.append(f"  let w = {_expr(draw, xs + us + ['s'])}")  # a let that may read actions
    lines.append("  dt = 0.1")
    if kind != "map":
        lines.append(f"  integrator {kind}(substeps = {draw(st.integers(1, 3))})")
    lines.append("  ode {" if kind != "map" else "  map {")
    for i, x in enumerate(xs):
        rhs = f"{_expr(draw, xs + us + ['s', 'w'])} + {us[i % m]}"
        lines.append(f"    {x}{chr(39) if kind != 'map' else ''} = {x if kind == 'map' else '0'} + {rhs}")
    lines += ["  }", "}"]
    centre = ", ".join(draw(st.sampled_from(["0", "0.5", "-0.5", "1"])) for _ in xs)
    lines.append(f"region goal = ball([{centre}], {draw(st.sampled_from(['0.5', '1', '1.5']))})")
    lines.append(f"region unsafe = box(x0 in [{draw(st.sampled_from(['1', '2']))}, 3])")
    lines.append(f"region mid = ball({{s: 0.5}}, 0.7)")
    atoms = ["in goal", "in unsafe", "in mid", f"x0 > {draw(st.sampled_from(['0', '0.5']))}",
             f"abs(s) <= 1", f"{_expr(draw, xs + ['s'])} < 1"]
    lines.append(f"formula f = {_formula(draw, atoms)}")
    asap = draw(st.sampled_from(["in goal", "in goal and f", "f", _formula(draw, atoms)]))
    avoid = draw(st.sampled_from([None, "in unsafe", "f", _formula(draw, atoms)]))
    deadline = draw(st.integers(5, 25))
    kmin = draw(st.integers(1, deadline))
    reward = draw(st.sampled_from(["asap", "rho", "rho(window = 3)", "distance"]))
    task = [f"task t {{ asap {asap}"]
    if avoid:
        task.append(f"  avoid {avoid}")
    task += [f"  deadline {deadline}", f"  episode {kmin}..{deadline}", f"  reward {reward}"]
    if draw(st.booleans()):
        task.append("  observe state, time")
    lines += task + ["}"]
    return "\n".join(lines) + "\n"


def _load(text):
    try:
        return asap_dsl.loads(text, "fuzz.asap")
    except asap_dsl.SpecError:
        return None


# Batches of at least 2: at batch 1 the numpy core monitors with its scalar monitor, whose and/or
# and windows let a NaN atom (sqrt of a negative, 0/0) drop out where numpy's min/max (the batched
# monitor, and the compiled one) keep it; the benchmark specs above run at batch 1 too.
@settings(max_examples=fuzz_examples(8), deadline=None, suppress_health_check=list(HealthCheck), database=None)
@given(specs(), st.integers(2, 4), st.integers(0, 2**16))
def test_fuzzed_specs_agree_exactly(text, n, seed):
    prog = _load(text)
    assume(prog is not None)
    try:
        make_vec_env(prog, "t", num_envs=1, engine="numpy")
    except ValueError:  # e.g. a distance reward without region atoms: refused by both, said there
        assume(False)
    agree(prog, "t", n=n, steps=60, seed=seed, action_seed=seed + 1, exact=True)


def _mutants():
    from test_fuzz import mutated

    return mutated()


@settings(max_examples=fuzz_examples(6), deadline=None, suppress_health_check=list(HealthCheck), database=None)
@given(_mutants())
def test_mutated_specs_that_load_agree(text):
    prog = _load(text)
    assume(prog is not None and prog.system.kind != "simulator")
    for task in prog.tasks[:1]:
        try:
            make_vec_env(prog, task, num_envs=1, engine="numpy")
        except ValueError:
            continue
        agree(prog, task, n=2, steps=40, exact=False)


# ---- the rest of the contract -------------------------------------------------------------------

def test_avoid_at_start_is_the_offline_value():
    prog = asap_dsl.load(EXAMPLES / "double_integrator.asap")
    core = with_engine(EnvCore(prog, "park", 3, None, autoreset=True), "native")
    states = np.random.default_rng(0).uniform(-4, 4, size=(200, 2))
    want = offline.satisfied(core.tm.avoid, states[:, None, :])[:, 0]
    assert np.array_equal(core.avoid_at_start(states), want) and want.any() and not want.all()


def test_single_env_and_check_env():
    from gymnasium.utils.env_checker import check_env

    path = SPECS / "bicycle.asap"
    a, b = make_env(path, "reach_avoid", seed=4, engine="numpy"), make_env(path, "reach_avoid", seed=4, engine="native")
    check_env(b, skip_render_check=True)
    a, b = make_env(path, "reach_avoid", seed=4, engine="numpy"), make_env(path, "reach_avoid", seed=4, engine="native")
    ra, rb = a.reset(), b.reset()
    assert np.array_equal(ra[0], rb[0]) and ra[1] == rb[1]
    for _ in range(40):
        act = a.action_space.sample()
        ra, rb = a.step(act), b.step(act)
        assert np.allclose(ra[0], rb[0], rtol=1e-6) and ra[2:4] == rb[2:4]
        if ra[2] or ra[3]:
            break


def test_engines_and_fallback(monkeypatch):
    prog = asap_dsl.load(SPECS / "dc_motor.asap")
    assert resolve_engine(None) == "numpy"  # the suite's default (conftest)
    monkeypatch.delenv("ASAP_ENGINE")
    assert resolve_engine(None) == "auto"
    assert isinstance(make_vec_env(prog, "reach", engine="auto").core, NativeCore)
    assert isinstance(make_vec_env(prog, "reach", engine="numpy").core, EnvCore)
    with pytest.raises(ValueError, match="unknown engine 'fast'; choose auto, native or numpy"):
        make_vec_env(prog, "reach", engine="fast")
    monkeypatch.setattr("asap_dsl.native.core.MAX_LINES", 10)  # too big to compile: numpy, said why
    assert isinstance(make_vec_env(prog, "reach", engine="auto").core, EnvCore)
    with pytest.raises(ValueError, match="does not cover task reach: its step is"):
        make_vec_env(prog, "reach", engine="native")


def test_second_start_loads_machine_code_from_the_cache(tmp_path, monkeypatch):
    import subprocess
    import sys

    monkeypatch.setenv("ASAP_CACHE_DIR", str(tmp_path))
    code = ("import asap_dsl; e = asap_dsl.make_vec_env('specs/dc_motor.asap', 'reach', engine='native', "
            "reward='rho(window = 7)'); print(e.core.compiled_from_cache, e.core.compile_seconds)")
    first = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    second = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert first.stdout.split()[0] == "False" and second.stdout.split()[0] == "True"
    assert float(second.stdout.split()[1]) < float(first.stdout.split()[1])
    assert list((tmp_path / "native").glob("step_*.py"))


def test_bad_actions_are_one_sentence():
    env = make_vec_env(SPECS / "attitude.asap", "reach", num_envs=2, engine="native")
    env.reset()
    with pytest.raises(ValueError, match=r"actions must have shape \[2, 3\]"):
        env.step(np.zeros((2, 2)))
    obs, r, d, i = env.step([[0, 0, 0], [1, 1, 1]])  # lists and ints work
    assert obs.dtype == np.float32 and r.dtype == np.float32


def test_compiled_step_is_faster_than_numpy():
    """A sanity bound, far below what benchmarks/envs.py measures (noisy machines)."""
    env = {e: make_vec_env(SPECS / "attitude.asap", "reach_avoid", num_envs=8, seed=0, engine=e) for e in ("numpy", "native")}
    act = np.zeros((8, 3), dtype=np.float32)
    cost = {}
    for e, v in env.items():
        v.reset()
        v.step(act)
        t0 = time.perf_counter()
        for _ in range(50):
            v.step(act)
        cost[e] = time.perf_counter() - t0
    assert cost["native"] * 5 < cost["numpy"]
