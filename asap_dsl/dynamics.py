"""The one-step map of an ``ode`` or ``map`` system, for numpy (batched) and CasADi (symbolic).

One definition of the discretisation serves the simulator and the oracle, so that the oracle's
minimum time is the minimum time of the very system the policies are trained on:

* ``rk4(substeps=N)`` / ``euler(substeps=N)``: N fixed sub-steps per ``dt``, action held;
* ``exact``: zero-order hold, ``x+ = Ad x + Bd u + cd`` with ``[Ad Bd cd]`` from one matrix
  exponential of the affine dynamics (computed once);
* ``map``: the right-hand sides are the next state.
"""

from __future__ import annotations

import functools
from typing import Any, Callable

import numpy as np
import scipy.linalg

from .expr import casadi_namespace, compile_function
from .model import SystemModel


def affine_probe(f: Callable[[np.ndarray, np.ndarray], np.ndarray], n: int,
                 m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, c)`` with ``f(x, u) = A x + B u + c``, read off ``f`` at zero and at the unit vectors.

    :param f: a batched map ``f(states [1, n], actions [1, m]) -> values [1, k]``, affine in both
        (not checked: the caller knows it from the equations' degree).
    :param n: the number of states.
    :param m: the number of actions (0: ``B`` is ``[k, 0]``).
    :return: ``A [k, n]``, ``B [k, m]``, ``c [k]``.
    """
    zero_x, zero_u = np.zeros((1, n)), np.zeros((1, m))
    c = f(zero_x, zero_u)[0]
    k = c.shape[0]
    A = np.stack([f(np.eye(n)[i: i + 1], zero_u)[0] - c for i in range(n)], axis=1) if n else np.zeros((k, 0))
    B = np.stack([f(zero_x, np.eye(m)[j: j + 1])[0] - c for j in range(m)], axis=1) if m else np.zeros((k, 0))
    return A, B, c


def affine_parts(system: SystemModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, c)`` with ``f(x, u) = A x + B u + c``, read off the (checked linear) equations."""
    return affine_probe(system.rhs, system.n_state, system.n_action)


@functools.lru_cache(maxsize=64)
def _zoh_cached(n: int, m: int, dt: float, A: bytes, B: bytes, c: bytes):
    # Keyed by the matrices' bytes: every environment of one system shares one matrix exponential.
    A_ = np.frombuffer(A).reshape(n, n)
    B_ = np.frombuffer(B).reshape(n, m)
    c_ = np.frombuffer(c).reshape(n)
    # exp([[A, B, c], [0, 0, 0]] dt) = [[Ad, Bd, cd], [0, I, 0]]
    M = np.zeros((n + m + 1, n + m + 1))
    M[:n, :n], M[:n, n:n + m], M[:n, n + m] = A_, B_, c_
    with np.errstate(all="ignore"):  # stiff dynamics over a long dt: inf/NaN, which a step then carries
        E = scipy.linalg.expm(M * dt)
    return E[:n, :n].copy(), E[:n, n:n + m].copy(), E[:n, n + m].copy()


def zero_order_hold(system: SystemModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Ad, Bd, cd)``: the exact discretisation of linear dynamics over one ``dt``."""
    A, B, c = affine_parts(system)
    n, m = B.shape
    return _zoh_cached(n, m, float(system.dt), A.tobytes(), np.ascontiguousarray(B).tobytes(), c.tobytes())


def _integrate(f: Callable[[Any, Any], Any], x: Any, u: Any, h: float, substeps: int, method: str) -> Any:
    """Fixed-step integration over ``h`` with ``u`` held; works on numpy arrays and CasADi symbols."""
    dh = h / substeps
    for _ in range(substeps):
        if method == "euler":
            x = x + dh * f(x, u)
        else:
            k1 = f(x, u)
            k2 = f(x + (0.5 * dh) * k1, u)
            k3 = f(x + (0.5 * dh) * k2, u)
            k4 = f(x + dh * k3, u)
            x = x + (dh / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x


def numpy_step(system: SystemModel) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``step(states [B, n], actions [B, m]) -> next states [B, n]`` (actions already clipped)."""
    if system.kind == "simulator":
        raise TypeError(f"system {system.name} is a black-box simulator: it has no known dynamics")
    if system.kind == "map":
        return system.rhs
    if system.integrator.method == "exact":
        Ad, Bd, cd = zero_order_hold(system)
        AdT, BdT = Ad.T.copy(), Bd.T.copy()
        return lambda x, u: x @ AdT + u @ BdT + cd
    f = system.rhs
    method, substeps, dt = system.integrator.method, system.integrator.substeps, system.dt
    return lambda x, u: _integrate(f, x, u, dt, substeps, method)


def casadi_step(system: SystemModel):
    """A CasADi ``Function('step', [x, u], [x_next])`` with the simulator's own discretisation."""
    import casadi as ca

    if system.kind == "simulator":
        raise TypeError(f"system {system.name} is a black-box simulator: it has no known dynamics")
    n, m = system.n_state, system.n_action
    x = ca.SX.sym("x", n)
    u = ca.SX.sym("u", m)
    if system.kind == "ode" and system.integrator.method == "exact":
        Ad, Bd, cd = zero_order_hold(system)
        nxt = ca.DM(Ad) @ x + (ca.DM(Bd) @ u if m else 0) + ca.DM(cd)
        return ca.Function("step", [x, u], [nxt], ["x", "u"], ["x_next"])
    fn = compile_function(system.equations, system.symbols, casadi_namespace())

    def f(xx, uu):
        return ca.vertcat(*fn([xx[i] for i in range(n)], [uu[j] for j in range(m)]))

    if system.kind == "map":
        nxt = f(x, u)
    else:
        nxt = _integrate(f, x, u, system.dt, system.integrator.substeps, system.integrator.method)
    return ca.Function("step", [x, u], [nxt], ["x", "u"], ["x_next"])
