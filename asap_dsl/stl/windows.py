"""Sliding-window kernels over the last axis, O(T) whatever the window, vectorised over the rest.

All kernels work on any lattice numpy supports with ``np.maximum`` / ``np.minimum``: float64
robustness (bottom ``-inf``, top ``+inf``) and bool satisfaction (bottom ``False``, top ``True``).
``op`` is ``np.maximum`` (join) or ``np.minimum`` (meet) and ``ident`` its identity (the value of an
empty window).

Windows are cut at the ends of the trace: the samples outside ``[0, T-1]`` do not exist, so they
count as ``ident``.

* :func:`future_window` — ``y[t] = op x[t+lo .. t+hi]`` (``hi=None``: to the end of the trace);
* :func:`past_window` — ``y[t] = op x[t-hi .. t-lo]`` (``hi=None``: from the start);
* :func:`until_unbounded` — the strict unbounded until, ``W[s] = join_{k>=s} meet(psi[k],
  meet_{j in [s, k)} phi[j])``, by a blocked scan (O(T) work, O(sqrt T) vectorised Python steps).

Bounded windows use van Herk / Gil-Werman: the trace is cut into blocks of the window length ``w``;
one prefix and one suffix accumulation per block give any window as ``op(suffix[t],
prefix[t+w-1])``. Cost: two ``ufunc.accumulate`` passes and a few element-wise passes, whatever
``w`` is. Unbounded windows are one cumulative ``accumulate``.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

__all__ = ["future_window", "past_window", "shift_left", "shift_right", "until_unbounded"]


def shift_left(x: np.ndarray, k: int, ident) -> np.ndarray:
    """``y[..., t] = x[..., t + k]``, ``ident`` past the end."""
    return _shift(x, k, ident, forward=True)


def shift_right(x: np.ndarray, k: int, ident) -> np.ndarray:
    """``y[..., t] = x[..., t - k]``, ``ident`` before the start."""
    return _shift(x, k, ident, forward=False)


def _shift(x: np.ndarray, k: int, ident, forward: bool) -> np.ndarray:
    T = x.shape[-1]
    if k == 0:
        return x
    out = np.empty_like(x)
    if k >= T:
        out[...] = ident
    elif forward:
        out[..., : T - k] = x[..., k:]
        out[..., T - k :] = ident
    else:
        out[..., k:] = x[..., : T - k]
        out[..., :k] = ident
    return out


def _van_herk(z: np.ndarray, n_out: int, w: int, op, ident) -> np.ndarray:
    """``y[..., t] = op z[..., t .. t+w-1]`` for ``t < n_out`` (``ident`` past the end of z)."""
    lead = z.shape[:-1]
    L = -(-(n_out + w - 1) // w) * w
    zp = np.empty(lead + (L,), dtype=z.dtype)
    m = min(z.shape[-1], L)
    zp[..., :m] = z[..., :m]
    zp[..., m:] = ident
    blocks = zp.reshape(lead + (L // w, w))
    g = op.accumulate(blocks, axis=-1).reshape(lead + (L,))
    h = op.accumulate(blocks[..., ::-1], axis=-1)[..., ::-1].reshape(lead + (L,))
    return op(h[..., :n_out], g[..., w - 1 : w - 1 + n_out])


def future_window(x: np.ndarray, lo: int, hi: Optional[int], op, ident) -> np.ndarray:
    """``y[..., t] = op over x[..., t+lo .. t+hi]`` cut at the end (``ident`` when empty)."""
    T = x.shape[-1]
    if lo >= T:
        return np.full_like(x, ident)
    if hi is None or hi >= T - 1:
        s = op.accumulate(x[..., ::-1], axis=-1)[..., ::-1]
        return shift_left(s, lo, ident)
    w = hi - lo + 1
    if w == 1:
        return shift_left(x, lo, ident)
    return _van_herk(x[..., lo:], T, w, op, ident)


def past_window(x: np.ndarray, lo: int, hi: Optional[int], op, ident) -> np.ndarray:
    """``y[..., t] = op over x[..., t-hi .. t-lo]`` cut at the start (``ident`` when empty)."""
    T = x.shape[-1]
    if lo >= T:
        return np.full_like(x, ident)
    if hi is None or hi >= T - 1:
        return shift_right(op.accumulate(x, axis=-1), lo, ident)
    w = hi - lo + 1
    if w == 1:
        return shift_right(x, lo, ident)
    return np.ascontiguousarray(_van_herk(x[..., ::-1][..., lo:], T, w, op, ident)[..., ::-1])


def until_unbounded(phi: np.ndarray, psi: np.ndarray, bottom) -> np.ndarray:
    """Strict unbounded until over the last axis (future, cut at the end of the trace).

    ``W[s] = join_{k >= s} meet(psi[k], meet_{j in [s, k)} phi[j])``, i.e. the backward recursion
    ``W[s] = join(psi[s], meet(phi[s], W[s+1]))`` with ``W[T] = bottom``. Each step is the map
    ``x -> max(p, min(q, x))``; such maps compose in closed form (``P = max(p1, min(q1, p2))``,
    ``Q = min(q1, q2)``), so the trace is cut into ``K ~ sqrt(T)`` blocks: one backward pass inside
    all blocks at once (K vectorised steps), one pass over the block boundaries (T/K steps), and one
    element-wise fix-up. O(T) work, O(sqrt T) Python-level steps, vectorised over the leading axes.
    """
    join, meet = np.maximum, np.minimum
    lead = phi.shape[:-1]
    T = phi.shape[-1]
    K = max(1, int(math.isqrt(T - 1)) + 1) if T > 1 else 1
    nb = -(-T // K)
    L = nb * K
    dtype = phi.dtype
    p = np.full(lead + (L,), bottom, dtype=dtype)
    q = np.full(lead + (L,), bottom, dtype=dtype)
    p[..., :T] = psi
    q[..., :T] = phi
    p = p.reshape(lead + (nb, K))
    q = q.reshape(lead + (nb, K))
    # Backward pass inside every block at once: P = local until assuming bottom after the block.
    P = np.empty_like(p)
    P[..., K - 1] = p[..., K - 1]
    tmp = np.empty(lead + (nb,), dtype=dtype)
    for j in range(K - 2, -1, -1):
        meet(q[..., j], P[..., j + 1], out=tmp)
        join(p[..., j], tmp, out=P[..., j])
    Q = meet.accumulate(q[..., ::-1], axis=-1)[..., ::-1]
    # The value entering each block from its right neighbour.
    W_in = np.empty(lead + (nb,), dtype=dtype)
    cur = np.full(lead, bottom, dtype=dtype)
    for i in range(nb - 1, -1, -1):
        W_in[..., i] = cur
        cur = join(P[..., i, 0], meet(Q[..., i, 0], cur))
    W = join(P, meet(Q, W_in[..., None]))
    return W.reshape(lead + (L,))[..., :T]
