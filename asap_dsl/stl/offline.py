"""Offline, batched STL semantics over the formula IR (:mod:`asap_dsl.stl.ir`).

Public functions
----------------
``robustness(node, traces, *, n_state=None) -> ndarray``
    traces float ``[B, T, n]`` or ``[T, n]`` -> float64 ``[B, T]`` / ``[T]``: ρ(s̄, t, φ) at every t.
``satisfied(node, traces, *, n_state=None) -> ndarray``
    the Boolean semantics, bool, same shape; computed on booleans (exact comparisons of the atoms),
    never by the sign of ρ.
``first_time(node, traces, *, n_state=None)``
    the first t with (s̄, t) ⊨ φ, as float (``inf`` when never): ``[B]`` or a scalar.

Semantics (discrete time, steps t = 0 .. T-1)
---------------------------------------------
* atoms: ``Atom.robustness`` / ``Atom.satisfied``; ``Const``: ±inf / True, False;
  ``not`` negates, ``and``/``or`` are min/max, ``a -> b`` is ``max(-a, b)`` (``not a or b``).
* ``always``/``eventually[lo, hi]``: min/max over ``t' in [t+lo, t+hi]``;
  ``historically``/``once[lo, hi]``: min/max over ``t' in [t-hi, t-lo]``. ``hi=None`` is unbounded.
* Finite traces: windows are cut at the ends of the trace; an empty window gives
  ``eventually``/``once`` -inf (False), ``always``/``historically`` +inf (True).
* ``until`` is **strict** in its left argument, as in the paper (eq. 2) and in rtamt 0.4.10's
  discrete-time monitor::

      ρ(φ U[a,b] ψ, t) = max_{t' in [t+a, t+b], t' <= T-1} min(ρ(ψ, t'), min_{t'' in [t, t')} ρ(φ, t''))

  (φ must hold from t up to, not including, the step where ψ holds; over an empty window -inf).
* ``since`` is the mirror image, strict as well::

      ρ(φ S[a,b] ψ, t) = max_{t' in [t-b, t-a], t' >= 0} min(ρ(ψ, t'), min_{t'' in (t', t]} ρ(φ, t''))

These match rtamt's discrete-time offline monitor at every step (not only where the windows fit);
``tests/test_stl_rtamt.py`` checks it on random formulas and traces.

Cost
----
O(T) per node whatever the window, vectorised over the batch: van Herk/Gil-Werman for bounded
windows, cumulative min/max for unbounded ones (:mod:`asap_dsl.stl.windows`). Until uses the exact
lattice identities (valid for finite, cut traces)::

    φ U[a,b] ψ  (t) = min( G[0,a-1] φ (t),  V(t+a) )        (G term absent when a = 0)
    V(s) = min( F[0,b-a] ψ (s),  (φ U ψ)(s) )   if b is finite,   V = φ U ψ  otherwise

where ``φ U ψ`` is the unbounded strict until computed by a blocked scan (O(T) work, O(sqrt T)
vectorised Python steps, see :func:`asap_dsl.stl.windows.until_unbounded`). Since is evaluated as
until on the time-reversed signals. Shared sub-formula objects are evaluated once per call.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from . import ir
from .windows import future_window, past_window, shift_left, until_unbounded

__all__ = ["robustness", "satisfied", "first_time", "check_traces"]


class _Lattice:
    def __init__(self, boolean: bool):
        self.boolean = boolean
        if boolean:
            self.dtype = np.bool_
            self.bottom, self.top = False, True
        else:
            self.dtype = np.float64
            self.bottom, self.top = -np.inf, np.inf

    def neg(self, x):
        return np.logical_not(x) if self.boolean else np.negative(x)


_ROB = _Lattice(False)
_SAT = _Lattice(True)


def check_traces(traces, n_state: Optional[int] = None) -> tuple[np.ndarray, bool]:
    """Validate and convert traces; returns (float64 ``[B, T, n]``, was_single_trace)."""
    try:
        arr = np.asarray(traces, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"traces must be a numeric array: {exc}") from None
    if arr.ndim not in (2, 3):
        raise ValueError(
            f"traces must have shape [B, T, n_state] or [T, n_state]; got an array with "
            f"{arr.ndim} dimension(s), shape {arr.shape}"
        )
    single = arr.ndim == 2
    if single:
        arr = arr[None]
    B, T, n = arr.shape
    if T < 1:
        raise ValueError(f"traces must have at least one step (T >= 1); got shape {arr.shape[1 - single:]}")
    if n_state is not None and n != n_state:
        raise ValueError(f"traces have {n} state component(s) in the last dimension; expected {n_state}")
    if B and not np.isfinite(arr).all():
        bad = np.argwhere(~np.isfinite(arr))[0]
        b, t, i = (int(v) for v in bad)
        where = f"step {t}" if single else f"batch index {b}, step {t}"
        raise ValueError(f"traces contain a non-finite value ({arr[b, t, i]}) at {where}, state component {i}")
    return arr, single


def _atom_values(node: ir.Atom, traces: np.ndarray, lat: _Lattice) -> np.ndarray:
    fn = node.satisfied if lat.boolean else node.robustness
    val = np.asarray(fn(traces))
    want = traces.shape[:-1]
    if val.shape != want:
        try:
            val = np.broadcast_to(val, want)
        except ValueError:
            raise ValueError(
                f"atom {node.text!r} returned shape {val.shape}; expected {want}"
            ) from None
    val = val.astype(lat.dtype, copy=False)
    if not lat.boolean and np.isnan(val).any():
        b, t = (int(v) for v in np.argwhere(np.isnan(val))[0])
        raise ValueError(f"atom {node.text!r} gave NaN robustness at batch index {b}, step {t}")
    return val


def _until(phi: np.ndarray, psi: np.ndarray, interval: ir.Interval, lat: _Lattice) -> np.ndarray:
    lo, hi = interval.lo, interval.hi
    T = phi.shape[-1]
    if lo >= T:
        return np.full_like(psi, lat.bottom)
    V = until_unbounded(phi, psi, lat.bottom)
    if hi is not None and hi - lo < T - 1:
        V = np.minimum(future_window(psi, 0, hi - lo, np.maximum, lat.bottom), V)
    V = shift_left(V, lo, lat.bottom)
    if lo > 0:
        V = np.minimum(future_window(phi, 0, lo - 1, np.minimum, lat.top), V)
    return V


def _eval(node: ir.Formula, traces: np.ndarray, lat: _Lattice, memo: dict) -> np.ndarray:
    key = id(node)
    hit = memo.get(key)
    if hit is not None:
        return hit[1]
    out = _eval_node(node, traces, lat, memo)
    memo[key] = (node, out)  # keep node alive so its id is not reused during this call
    return out


def _eval_node(node, traces, lat, memo):
    ev = lambda n: _eval(n, traces, lat, memo)  # noqa: E731
    if isinstance(node, ir.Atom):
        return _atom_values(node, traces, lat)
    if isinstance(node, ir.Const):
        return np.full(traces.shape[:-1], lat.top if node.value else lat.bottom, dtype=lat.dtype)
    if isinstance(node, ir.Not):
        return lat.neg(ev(node.arg))
    if isinstance(node, ir.And):
        return np.minimum(ev(node.left), ev(node.right))
    if isinstance(node, ir.Or):
        return np.maximum(ev(node.left), ev(node.right))
    if isinstance(node, ir.Implies):
        return np.maximum(lat.neg(ev(node.left)), ev(node.right))
    if isinstance(node, (ir.Always, ir.Eventually, ir.Historically, ir.Once)):
        x = ev(node.arg)
        lo, hi = node.interval.lo, node.interval.hi
        if isinstance(node, (ir.Always, ir.Historically)):
            op, ident = np.minimum, lat.top
        else:
            op, ident = np.maximum, lat.bottom
        kernel = future_window if isinstance(node, (ir.Always, ir.Eventually)) else past_window
        return kernel(x, lo, hi, op, ident)
    if isinstance(node, ir.Until):
        return _until(ev(node.left), ev(node.right), node.interval, lat)
    if isinstance(node, ir.Since):
        phi, psi = ev(node.left), ev(node.right)
        rev = _until(phi[..., ::-1], psi[..., ::-1], node.interval, lat)
        return np.ascontiguousarray(rev[..., ::-1])
    raise TypeError(f"not a formula node: {node!r}")


def _run(node, traces, lat, n_state):
    arr, single = check_traces(traces, n_state)
    out = _eval(node, arr, lat, {})
    out = np.array(out, dtype=lat.dtype, copy=True) if out.base is not None or not out.flags.writeable else out
    return out[0] if single else out


def robustness(node: ir.Formula, traces, *, n_state: Optional[int] = None) -> np.ndarray:
    """ρ(s̄, t, node) at every step: ``[B, T, n]`` -> ``[B, T]`` (``[T, n]`` -> ``[T]``), float64."""
    return _run(node, traces, _ROB, n_state)


def satisfied(node: ir.Formula, traces, *, n_state: Optional[int] = None) -> np.ndarray:
    """(s̄, t) ⊨ node at every step, exact Boolean semantics: bool, same shape as robustness."""
    return _run(node, traces, _SAT, n_state)


def first_time(node: ir.Formula, traces, *, n_state: Optional[int] = None):
    """First step t with (s̄, t) ⊨ node, as float64 (``inf`` when never): ``[B]`` or a scalar."""
    sat = satisfied(node, traces, n_state=n_state)
    hit = sat.any(axis=-1)
    idx = sat.argmax(axis=-1).astype(np.float64)
    out = np.where(hit, idx, np.inf)
    return np.float64(out) if sat.ndim == 1 else out
