"""Batched simulators: discretisation against references, the MuJoCo swimmer, user factories."""

from pathlib import Path

import numpy as np
import pytest
import scipy.integrate
import scipy.signal

import asap_dsl
from asap_dsl.dynamics import numpy_step
from asap_dsl.sim import SimulatorError, build_simulator

ROOT = Path(__file__).resolve().parent.parent
SPECS = ROOT / "specs"
FIXTURES = Path(__file__).resolve().parent / "fixtures"


@pytest.fixture
def user_path(monkeypatch):
    monkeypatch.syspath_prepend(str(FIXTURES))
    import user_sims

    user_sims.CALLS.clear()
    return user_sims


def test_rk4_matches_solve_ivp_on_attitude():
    prog = asap_dsl.load(SPECS / "attitude.asap")
    sysm = prog.system
    sim = build_simulator(sysm, batch=8)
    rng = np.random.default_rng(0)
    x0 = rng.uniform(sysm.init_low, sysm.init_high, size=(8, 6))
    u = rng.uniform(sysm.action_low, sysm.action_high, size=(8, 3))
    sim.reset(x0)
    got = x0
    for _ in range(3):  # three steps, action held
        got = sim.step(u)
    f = sysm.rhs
    for b in range(8):
        sol = scipy.integrate.solve_ivp(lambda t, x: f(x[None], u[b][None])[0], (0, 0.3), x0[b],
                                        method="DOP853", rtol=1e-12, atol=1e-12)
        ref = sol.y[:, -1]
        assert np.allclose(got[b], ref, rtol=0, atol=2e-5), (got[b], ref)
    # The check can fail: one Euler step per dt is far off the reference.
    assert np.abs(x0 + 0.3 * f(x0, u) - got).max() > 1e-3


def test_exact_matches_cont2discrete_dc_motor():
    prog = asap_dsl.load(SPECS / "dc_motor.asap")
    A = np.array([[0, 1, 0], [0, -10, 1], [0, -0.02, -2]], dtype=float)
    B = np.array([[0], [0], [2]], dtype=float)
    Ad, Bd, *_ = scipy.signal.cont2discrete((A, B, np.eye(3), np.zeros((3, 1))), 0.1, method="zoh")
    step = numpy_step(prog.system)
    rng = np.random.default_rng(1)
    x = rng.uniform(-5, 5, size=(16, 3))
    u = rng.uniform(-20, 20, size=(16, 1))
    assert np.allclose(step(x, u), x @ Ad.T + u @ Bd.T, rtol=1e-12, atol=1e-12)
    # through the simulator, actions are clipped to the action bounds (|V| <= 20)
    sim = build_simulator(prog.system, batch=16)
    sim.reset(x)
    assert np.allclose(sim.step(u * 100), x @ Ad.T + np.clip(u * 100, -20, 20) @ Bd.T, atol=1e-9)


def test_exact_on_nonlinear_ode_is_refused():
    text = (SPECS / "attitude.asap").read_text().replace("integrator rk4(substeps = 4)", "integrator exact")
    with pytest.raises(asap_dsl.SpecError) as err:
        asap_dsl.loads(text, "attitude_exact.asap")
    assert any(d.code == "E111" for d in err.value.diagnostics)


# ---- MuJoCo swimmer ----------------------------------------------------------------------------


def test_swimmer_matches_gymnasium_swimmer():
    pytest.importorskip("imageio")  # gymnasium's MuJoCo envs import it (test-only dependency)
    import gymnasium as gym

    prog = asap_dsl.load(SPECS / "swimmer.asap")
    sim = build_simulator(prog.system, batch=3)
    assert (sim.state_dim, sim.action_dim, sim.dt) == (10, 2, pytest.approx(0.04))
    rng = np.random.default_rng(2)
    s0 = rng.uniform(-0.3, 0.3, size=(3, 10))
    assert np.allclose(sim.reset(s0), s0)
    ref = gym.make("Swimmer-v5", exclude_current_positions_from_observation=False).unwrapped
    ref.reset(seed=0)
    for b in range(3):
        ref.set_state(s0[b, :5], s0[b, 5:])
        a = rng.uniform(-1, 1, size=2)
        for _ in range(5):
            ref_obs, *_ = ref.step(np.clip(3 * a, -1, 1))
        sub = build_simulator(prog.system, batch=1)
        sub.reset(s0[b:b + 1])
        for _ in range(5):
            got = sub.step(a[None] * 3)  # clipped to [-1, 1] like the actuators
        assert np.allclose(got[0], ref_obs, atol=1e-9), (got[0], ref_obs)


def test_swimmer_batch_is_bit_identical_to_one_mjdata_per_env(monkeypatch):
    """The threaded mujoco.batch path against the per-MjData mj_step loop (the fallback on MuJoCo < 4)."""
    from asap_dsl.sim import mujoco_swimmer
    from asap_dsl.sim.mujoco_swimmer import MujocoSwimmer

    B = 24
    threaded = MujocoSwimmer(B, nthread=2)
    if threaded.data is not None:
        pytest.skip("this MuJoCo has no mujoco.batch")
    monkeypatch.setattr(mujoco_swimmer, "_mujoco_batch", lambda: None)  # as on MuJoCo < 4: one MjData each
    loop = MujocoSwimmer(B)
    assert loop.data is not None and loop.nthread == 1
    rng = np.random.default_rng(5)
    s0 = rng.uniform(-2, 2, size=(B, 10))  # wide: joint limits (+-100 deg) engage the constraint solver
    assert np.array_equal(threaded.reset(s0), loop.reset(s0))
    for t in range(40):
        a = rng.uniform(-1.5, 1.5, size=(B, 2))
        assert np.array_equal(threaded.step(a), loop.step(a)), t
        if t % 10 == 3:
            mask = rng.random(B) < 0.4
            s = rng.uniform(-2, 2, size=(B, 10))
            assert np.array_equal(threaded.reset(s, mask=mask), loop.reset(s, mask=mask))


def test_swimmer_dt_mismatch_names_the_line():
    text = (SPECS / "swimmer.asap").read_text().replace("dt = 0.04", "dt = 0.05")
    prog = asap_dsl.loads(text, "swim.asap")
    with pytest.raises(SimulatorError, match=r"swim\.asap:\d+:\d+.*dt is 0\.04"):
        build_simulator(prog.system, batch=1, file=prog.file)


# ---- user factories ----------------------------------------------------------------------------

USER_SPEC = """
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


def user_prog(target: str):
    return asap_dsl.loads(USER_SPEC % target, "cart.asap")


# gymnasium's checker advises a [-1, 1] action box (this factory's is not, on purpose), in colour codes
@pytest.mark.filterwarnings("ignore:.*symmetric and normalized space:UserWarning")
def test_user_factory_end_to_end(user_path):
    prog = user_prog("user_sims:double_integrator")
    assert user_path.CALLS == []  # never called at load time
    env = asap_dsl.make_env(prog, seed=0)
    assert user_path.CALLS == ["double_integrator"]
    from gymnasium.utils.env_checker import check_env

    check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=3)
    reached = None
    for _ in range(40):
        a = [2.0] if obs[0] < 3 - 0.5 * obs[1] * abs(obs[1]) / 2 else [-2.0]
        obs, r, term, trunc, info = env.step(a)
        if info["t_reach"] is not None and reached is None:
            reached = info["t_reach"]
        if term or trunc:
            break
    assert reached is not None and info["end_reason"] == "time_limit"
    venv = asap_dsl.make_vec_env(prog, num_envs=4, seed=0)
    venv.reset()
    o, r, d, infos = venv.step(np.ones((4, 1)))
    assert o.shape == (4, 2)


def test_factory_with_batch_argument(user_path):
    asap_dsl.make_vec_env(user_prog("user_sims:batched"), num_envs=5, seed=0)
    assert user_path.CALLS == [("batched", 5)]


@pytest.mark.parametrize("target, message", [
    ("no_such_module_xyz:make", r"cannot import module 'no_such_module_xyz'"),
    ("user_sims:nope", r"has no attribute 'nope'"),
    ("user_sims:not_callable", r"not callable"),
    ("user_sims:factory_raises", r"factory raised OSError: licence server unreachable"),
    ("user_sims:missing_step", r"lacks step"),
    ("user_sims:wrong_dims", r"state_dim is 3 but the system declares 2"),
    ("user_sims:wrong_shape", r"step returned shape \(1, 3\); expected \(1, 2\)"),
    ("user_sims:raises_in_step", r"step raised RuntimeError: solver diverged"),
    ("sys:exit", r"factory raised SystemExit"),  # would end the process silently with status 0
])
def test_broken_factory_names_the_spec_line(user_path, target, message):
    prog = user_prog(target)
    with pytest.raises(SimulatorError) as err:
        env = asap_dsl.make_env(prog, seed=0)
        env.reset()
        env.step([0.0])
    text = str(err.value)
    assert text.startswith("cart.asap:7:3"), text
    assert f'"{target}"' in text
    import re

    assert re.search(message, text), text
