"""The whole environment step of one task as the source of one numba module.

:func:`generate` writes, from a :class:`~asap_dsl.native.episode.StepSpec`, the functions the
compiled core calls, each a loop over the batch:

* ``step(actions, F, I, obs, rew32, flags) -> finished entries`` (``ode`` and ``map``): the actions
  clipped, the dynamics with the integrator's substeps, the rest of the step
  (:func:`~asap_dsl.native.episode.finish_lines`), then, with autoreset, the finished entries'
  fresh episodes drawn from the numpy generator's stream (:mod:`.draws`) and started; -1 when
  no initial state outside ``avoid`` could be drawn;
* ``post(new, F, I, obs, rew32, flags)`` (black-box simulators): the same from the states the simulator
  reached, without the autoreset (the simulator is reset in Python);
* ``restart(mask, F, I, obs)``: the masked entries start (step 0) at the state in their
  ``cand`` columns, with the episode length in their ``kc`` column.

``F [B + 1, ·]`` (float64) and ``I [B + 1, ·]`` (int64) hold every entry's values
(:class:`~asap_dsl.native.episode.Cols`, then the monitors' own); row ``B`` is scratch for the
checks of candidate initial states, and its ``I`` row holds the autoreset flag and the
generator's addresses. ``obs`` and ``rew32`` (float32, what SB3 stores) are written afresh each
step; ``flags [5, B]``: terminated, truncated, done, done only by a non-finite
value found after the end reasons (its fresh episode is drawn after the others', as the numpy
core does), and asap satisfied (info's).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..dynamics import zero_order_hold
from . import draws
from .episode import Cols, StepSpec, distance_term, finish_lines, start_lines
from .exprs import PRELUDE, Body, NotCovered, mn, mx, number
from .monitors import Layout, MonitorCode


@dataclass
class Kernel:
    """The generated module's source, the widths of the rows and where the columns are."""

    source: str
    nf: int
    ni: int
    cols: Cols
    black_box: bool


def _tuple(items: list[str]) -> str:
    return "(" + ", ".join(items) + ("," if len(items) == 1 else "") + ")"


def _indent(lines: list[str], ind: str) -> list[str]:
    return [ind + line for line in lines]


def _function(name: str, args: str, body: Body, ret: str) -> list[str]:
    return ["", "", "@njit(**_JIT)", f"def {name}({args}):", *body.lines, f"    return {ret}"]


def _rhs(spec: StepSpec) -> list[str]:
    """``_rhs(S, A)``: the right-hand sides (an ODE's derivative, a map's next state)."""
    body = Body(spec.system.symbols)
    vals = [body.expr(e) for e in spec.system.equations]
    return _function("_rhs", "S, A", body, _tuple(vals))


def _advance(spec: StepSpec) -> list[str]:
    """Lines computing ``N``, the next state, from ``S`` and ``A`` held over ``dt``:
    :func:`asap_dsl.dynamics.numpy_step`'s integrator, the same operations in the same order."""
    sysm = spec.system
    n, m = sysm.n_state, sysm.n_action
    if sysm.kind == "map":
        return ["N = _rhs(S, A)"]
    if sysm.integrator.method == "exact":
        Ad, Bd, cd = zero_order_hold(sysm)
        nxt = []
        for j in range(n):  # x @ Ad.T + u @ Bd.T + cd, each product summed in order (BLAS's may differ)
            xs = " + ".join(f"S[{i}] * {number(Ad[j, i])}" for i in range(n)) or "0.0"
            us = " + ".join(f"A[{k}] * {number(Bd[j, k])}" for k in range(m)) or "0.0"
            nxt.append(f"(({xs}) + ({us})) + {number(cd[j])}")
        return [f"N = {_tuple(nxt)}"]
    substeps = sysm.integrator.substeps
    dh = float(sysm.dt) / substeps
    X = _tuple([f"x{i}" for i in range(n)])
    L = [f"{X} = S", f"for _ in range({substeps}):", f"    k1 = _rhs({X}, A)"]
    if sysm.integrator.method == "euler":
        L += [f"    x{i} = x{i} + {number(dh)} * k1[{i}]" for i in range(n)]
    else:
        h2, h6 = 0.5 * dh, dh / 6.0
        L.append(f"    k2 = _rhs({_tuple([f'x{i} + {number(h2)} * k1[{i}]' for i in range(n)])}, A)")
        L.append(f"    k3 = _rhs({_tuple([f'x{i} + {number(h2)} * k2[{i}]' for i in range(n)])}, A)")
        L.append(f"    k4 = _rhs({_tuple([f'x{i} + {number(dh)} * k3[{i}]' for i in range(n)])}, A)")
        L += [f"    x{i} = x{i} + {number(h6)} * (((k1[{i}] + 2.0 * k2[{i}]) + 2.0 * k3[{i}]) + k4[{i}])"
              for i in range(n)]
    return L + [f"N = {X}"]


def _observe(spec: StepSpec, layout: Layout) -> list[str]:
    """``_observe(S, t, F, I, b)``: the atoms and monitors at state ``S``, step ``t`` of entry
    ``b``; returns (asap ρ, asap lane 1, avoid ρ, avoid lane 1, the reward's own value)."""
    body = Body(spec.system.symbols)
    mon = MonitorCode(body, layout, lambda r: spec.regions[r])
    ar, asat = mon.tracker(spec.asap, 2)
    vr, vsat = mon.tracker(spec.avoid, 2) if spec.avoid is not None else ("0.0", "-1.0")
    rw = spec.reward
    if rw.kind == "rho":
        q = mon.tracker(rw.node, 1)[0]
    elif rw.kind == "distance":
        q = distance_term(body, rw)
    else:
        q = "0.0"
    return _function("_observe", "S, t, F, I, b", body, _tuple([ar, asat, vr, vsat, q]))


def _autoreset(spec: StepSpec, c: Cols) -> list[str]:
    """Lines (after the loop over the entries) giving the finished entries fresh episodes: the
    draws of :func:`asap_dsl.sampling.initial_states` and ``rng.integers``, for the entries ended
    by the end reasons first, then for those a non-finite value ended (the numpy core's order)."""
    n = spec.system.n_state
    low, high = np.asarray(spec.init_low, dtype=float), np.asarray(spec.init_high, dtype=float)
    row = f"F[b, {c.cand} + {{i}}]"
    ingroup = "flags[2, b] and flags[3, b] == (g == 1)"
    X = _tuple([f"F[b, {c.cand + i}]" for i in range(n)])
    L = [f"if ndone > 0 and I[B, {c.autoreset}] != 0:",
         f"    RS, RD, RU = I[B, {c.rs}], I[B, {c.rd}], I[B, {c.ru}]",
         "    for g in range(2):",
         "        m = 0",
         "        for b in range(B):",
         f"            if {ingroup}:",
         *draws.uniform_row(row, low, high, " " * 16),
         "                m += 1",
         "        if m == 0:",
         "            continue"]
    if spec.avoid is not None:  # initial_states: redraw the rows where avoid holds, 100 rounds at most
        L += ["        rounds = 0",
              "        while True:",
              "            nbad = 0",
              "            for b in range(B):",
              f"                if {ingroup}:",
              f"                    vsat = _observe({X}, zero, F, I, B)[3]",
              f"                    I[b, {c.bad}] = 1 if vsat > 0.0 else 0",
              "                    if vsat > 0.0:",
              "                        nbad += 1",
              "            if nbad == 0:",
              "                break",
              "            rounds += 1",
              "            if rounds == 100:",
              "                return -1",
              "            for b in range(B):",
              f"                if {ingroup} and I[b, {c.bad}] != 0:",
              *draws.uniform_row(row, low, high, " " * 20)]
    kmin, kmax = spec.episode
    L += ["        for b in range(B):",
          f"            if {ingroup}:",
          *draws.bounded_integer(f"I[b, {c.kc}]", kmin, kmax, " " * 16),
          "    restart(flags[2], F, I, obs)"]
    return L


def generate(spec: StepSpec) -> Kernel:
    """The source of the compiled step of ``spec`` (see the module docstring)."""
    sysm = spec.system
    if sysm.kind not in ("ode", "map", "simulator"):
        raise NotCovered(f"a system of kind {sysm.kind}")
    if not np.all(np.isfinite(np.subtract(spec.init_high, spec.init_low))):
        raise NotCovered("an initial box wider than the largest float")
    n, m = sysm.n_state, sysm.n_action
    lay = Layout()
    lay.f(n)  # the state: F[b, 0:n]
    c = Cols(n=n, n_obs=n + (1 if spec.observe_time else 0), arob=lay.f())
    c.t, c.k, c.t_reach, c.end, c.asat, c.vsat = (lay.i() for _ in range(6))
    black_box = sysm.kind == "simulator"
    src = [PRELUDE, draws.INTRINSICS]
    if not black_box and (sysm.kind == "map" or sysm.integrator.method != "exact"):
        src += _rhs(spec)
    src += _observe(spec, lay)  # the monitors' columns
    c.rew, c.rho, c.final, c.final_obs, c.cand = lay.f(), lay.f(), lay.f(n), lay.f(c.n_obs), lay.f(n)
    c.info_t_reach, c.info_end, c.info_t, c.kc, c.bad = (lay.i() for _ in range(5))
    c.autoreset, c.rs, c.rd, c.ru = (lay.i() for _ in range(4))
    head = ["", "", "@njit(**_JIT)"]
    loop = ["    B = F.shape[0] - 1", "    zero = B - B  # step 0 typed as the steps are",
            "    ndone = 0", "    for b in range(B):", f"        S = {_tuple([f'F[b, {i}]' for i in range(n)])}"]
    if black_box:
        src += head + ["def post(new, F, I, obs, rew32, flags):", *loop,
                       f"        N = {_tuple([f'new[b, {i}]' for i in range(n)])}",
                       *_indent(finish_lines(spec, c), " " * 8), "    return ndone"]
    else:
        lo, hi = sysm.action_low, sysm.action_high
        clip = []
        for j in range(m):  # CheckedSimulator.step's np.clip into the action bounds
            clip += [f"a{j} = np.float64(actions[b, {j}])", f"a{j} = {mx(f'a{j}', number(lo[j]))}",
                     f"a{j} = {mn(f'a{j}', number(hi[j]))}"]
        src += head + ["def step(actions, F, I, obs, rew32, flags):", *loop,
                       *_indent(clip + [f"A = {_tuple([f'a{j}' for j in range(m)])}"] + _advance(spec), " " * 8),
                       *_indent(finish_lines(spec, c), " " * 8),
                       *_indent(_autoreset(spec, c), "    "), "    return ndone"]
    X = _tuple([f"F[b, {c.cand + i}]" for i in range(n)])
    restart = head + ["def restart(mask, F, I, obs):", "    zero = F.shape[0] - F.shape[0]",
                      "    for b in range(F.shape[0] - 1):", "        if mask[b]:",
                      *_indent(start_lines(spec, c, X, f"I[b, {c.kc}]"), " " * 12), "    return 0"]
    src[2:2] = restart  # before step, which calls it
    return Kernel("\n".join(src) + "\n", lay.nf, lay.ni, c, black_box)
