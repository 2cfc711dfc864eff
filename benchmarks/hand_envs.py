"""The peers of benchmarks/envs.py: what a user would write instead of a spec.

* :class:`HandEnv` — a gymnasium-style env written by hand: the same ODE as the spec in Python
  floats, RK4 with 4 substeps per step, the task's two balls (goal: an ASAP-style reward and
  ``satisfied``; unsafe and leaving the state space: terminated; the deadline: truncated), initial
  states uniform in the spec's box. No monitors, no checks: the cheapest honest env.
* :data:`KERNELS` — the dynamics alone as a numba kernel over the batch (RK4 with 4 substeps; the
  DC motor's exact zero-order hold as the spec has it): a lower bound for any environment step.

The numbers are the specs' own (specs/*.asap).
"""

from __future__ import annotations

import math
import random

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numba import njit

L_F, L_R = 1.105, 1.738
BETA = L_R / (L_F + L_R)


def attitude(x, u):
    w1, w2, w3, p1, p2, p3 = x
    s = p1 * p1 + p2 * p2 + p3 * p3
    return (0.25 * (u[0] + w2 * w3), 0.5 * (u[1] - 3 * w1 * w3), u[2] + 2 * w1 * w2,
            0.5 * (w2 * (s - p3) + w3 * (s + p2) + w1 * (s + 1)),
            0.5 * (w1 * (s + p3) + w3 * (s - p1) + w2 * (s + 1)),
            0.5 * (w1 * (s - p2) + w2 * (s + p1) + w3 * (s + 1)))


def bicycle(x, u):
    _, _, psi, v = x
    beta = math.atan(BETA * math.tan(u[0]))
    return (v * math.cos(psi + beta), v * math.sin(psi + beta), v / L_R * math.sin(beta), u[1])


def dc_motor(x, u):
    _, omega, i = x
    return (omega, (0.01 * i - 0.1 * omega) / 0.01, (u[0] - i - 0.01 * omega) / 0.5)


#: name -> (dynamics, state bounds, init box, action bounds, goal (centre, r), unsafe (centre, r))
SYSTEMS = {
    "attitude": (attitude, [(-4, 4)] * 3 + [(-2, 2)] * 3, [(-0.7, 0.7)] * 3 + [(-0.9, 0.9)] * 3, [(-1.2, 1.2)] * 3,
                 ([0.0] * 6, 0.8), ([0, 0, 0.2, 0, 0, 0], 0.3)),
    "bicycle": (bicycle, [(-5, 5), (-5, 5), (-2 * math.pi, 2 * math.pi), (-2, 4)],
                [(-1.5, 1.5), (-1.5, 1.5), (-math.pi / 4, math.pi / 4), (0, 2)], [(-0.7, 0.7), (-4, 4)],
                ([1, 1, 0, math.sqrt(2)], 0.8), ([0.5, 0.5, 0, math.sqrt(2) / 2], 0.3)),
    "dc_motor": (dc_motor, [(-4, 4), (-100, 100), (-100, 100)], [(-math.pi, math.pi), (-5, 5), (-5, 5)], [(-20, 20)],
                 ([math.pi / 2, 0, 0], 0.5), ([math.pi / 4, 0, 0], 0.2)),
}


def _dist(x, c):
    return math.sqrt(sum((a - b) * (a - b) for a, b in zip(x, c)))


class HandEnv(gym.Env):
    """The ODE in Python floats, RK4 (4 substeps), two balls; see the module docstring."""

    def __init__(self, name: str, dt: float = 0.1, deadline: int = 30):
        self.f, self.bounds, self.init, self.abounds, self.goal, self.unsafe = SYSTEMS[name]
        self.dt, self.deadline = dt, deadline
        lo, hi = np.array(self.bounds, dtype=np.float32).T
        self.observation_space = spaces.Box(lo, hi, dtype=np.float32)
        alo, ahi = np.array(self.abounds, dtype=np.float32).T
        self.action_space = spaces.Box(alo, ahi, dtype=np.float32)
        self.rng = random.Random(0)
        self.r_sat = self.deadline + 2.0

    def reset(self, *, seed=None, options=None):
        if seed is not None:
            self.rng.seed(seed)
        while True:
            self.x = [self.rng.uniform(a, b) for a, b in self.init]
            if _dist(self.x, self.unsafe[0]) > self.unsafe[1]:
                break
        self.t = 0
        return np.array(self.x, dtype=np.float32), {}

    def step(self, action):
        u = [min(max(float(a), lo), hi) for a, (lo, hi) in zip(action, self.abounds)]
        f, x, h = self.f, self.x, self.dt / 4
        for _ in range(4):
            k1 = f(x, u)
            k2 = f([a + 0.5 * h * k for a, k in zip(x, k1)], u)
            k3 = f([a + 0.5 * h * k for a, k in zip(x, k2)], u)
            k4 = f([a + h * k for a, k in zip(x, k3)], u)
            x = [a + h / 6 * (p + 2 * q + 2 * r + s) for a, p, q, r, s in zip(x, k1, k2, k3, k4)]
        self.x, self.t = x, self.t + 1
        rho = self.goal[1] - _dist(x, self.goal[0])
        sat = rho >= 0
        bad = _dist(x, self.unsafe[0]) <= self.unsafe[1] or any(not lo <= a <= hi for a, (lo, hi) in zip(x, self.bounds))
        reward = self.r_sat if sat and not bad else rho
        info = {"rho": rho, "satisfied": sat}
        return np.array(x, dtype=np.float32), reward, bad, self.t >= self.deadline, info


# ---- the dynamics alone, compiled ----------------------------------------------------------------

@njit
def _attitude(x, u):
    w1, w2, w3, p1, p2, p3 = x[0], x[1], x[2], x[3], x[4], x[5]
    s = p1 * p1 + p2 * p2 + p3 * p3
    return (0.25 * (u[0] + w2 * w3), 0.5 * (u[1] - 3 * w1 * w3), u[2] + 2 * w1 * w2,
            0.5 * (w2 * (s - p3) + w3 * (s + p2) + w1 * (s + 1)),
            0.5 * (w1 * (s + p3) + w3 * (s - p1) + w2 * (s + 1)),
            0.5 * (w1 * (s - p2) + w2 * (s + p1) + w3 * (s + 1)))


@njit
def _bicycle(x, u):
    beta = math.atan(BETA * math.tan(u[0]))
    return (x[3] * math.cos(x[2] + beta), x[3] * math.sin(x[2] + beta), x[3] / L_R * math.sin(beta), u[1])


def _axpy(n):
    terms = ", ".join(f"x[{i}] + a * k[{i}]" for i in range(n))
    rk4 = ", ".join(f"x[{i}] + c * (k1[{i}] + 2 * k2[{i}] + 2 * k3[{i}] + k4[{i}])" for i in range(n))
    ns: dict = {}
    exec(f"def axpy(x, a, k):\n    return ({terms},)\n"  # noqa: S102 - the same line per component
         f"def rk4(x, c, k1, k2, k3, k4):\n    return ({rk4},)\n", ns)
    return njit(ns["axpy"]), njit(ns["rk4"])


def _rk4_kernel(f, n, m):
    """RK4 with 4 substeps, the state and the action as tuples (registers: nothing in memory)."""
    axpy, comb = _axpy(n)

    @njit  # a closure over f: compiled in each run
    def step(X, U):
        h = 0.1 / 4
        for b in range(X.shape[0]):
            u = (U[b, 0], U[b, 1], U[b, 2]) if m == 3 else (U[b, 0], U[b, 1])
            x = (X[b, 0], X[b, 1], X[b, 2], X[b, 3], X[b, 4], X[b, 5]) if n == 6 else (X[b, 0], X[b, 1], X[b, 2], X[b, 3])
            for _ in range(4):
                k1 = f(x, u)
                k2 = f(axpy(x, 0.5 * h, k1), u)
                k3 = f(axpy(x, 0.5 * h, k2), u)
                k4 = f(axpy(x, h, k3), u)
                x = comb(x, h / 6, k1, k2, k3, k4)
            for i in range(n):
                X[b, i] = x[i]
        return X
    return step


def _exact_kernel(Ad, Bd):
    AdT, BdT = np.ascontiguousarray(Ad.T), np.ascontiguousarray(Bd.T)

    @njit  # the matrices are constants of the closure
    def step(X, U):
        n, m = AdT.shape[0], BdT.shape[0]
        for b in range(X.shape[0]):
            y = np.zeros(n)
            for j in range(n):
                for i in range(n):
                    y[j] += X[b, i] * AdT[i, j]
                for k in range(m):
                    y[j] += U[b, k] * BdT[k, j]
            for j in range(n):
                X[b, j] = y[j]
        return X
    return step


def kernel(name: str, program=None):
    """``step(X [B, n] float64, U [B, m]) -> X`` in place: the named system's dynamics alone."""
    if name == "attitude":
        return _rk4_kernel(_attitude, 6, 3)
    if name == "bicycle":
        return _rk4_kernel(_bicycle, 4, 2)
    from asap_dsl.dynamics import zero_order_hold

    Ad, Bd, _ = zero_order_hold(program.system)  # the motor's c is 0
    return _exact_kernel(Ad, Bd)
