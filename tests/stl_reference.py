"""Test helpers for the STL evaluators: a naive reference semantics and hypothesis strategies.

The reference is a literal transcription of the definitions in ``asap_dsl/stl/offline.py``'s
docstring (one trace, Python loops, O(T * window)); it knows nothing of the fast kernels.
"""

from __future__ import annotations

import math
import os

import numpy as np
from hypothesis import strategies as st

from asap_dsl.stl import ir

INF = math.inf
FUZZ_EXAMPLES = int(os.environ.get("ASAP_FUZZ_EXAMPLES", "0") or 0)


def examples(default: int) -> int:
    """Number of hypothesis examples: ``ASAP_FUZZ_EXAMPLES`` if set, else ``default``."""
    return FUZZ_EXAMPLES or default


# ---- atoms ------------------------------------------------------------------------------------

def make_atom(i: int, op: str, c: float) -> ir.Atom:
    """``x_i op c`` for op in < <= > >=, robustness as rtamt computes it."""
    if op in ("<", "<="):
        rob = lambda s, i=i, c=c: c - s[..., i]  # noqa: E731
    else:
        rob = lambda s, i=i, c=c: s[..., i] - c  # noqa: E731
    sat = {
        "<": lambda s, i=i, c=c: s[..., i] < c,
        "<=": lambda s, i=i, c=c: s[..., i] <= c,
        ">": lambda s, i=i, c=c: s[..., i] > c,
        ">=": lambda s, i=i, c=c: s[..., i] >= c,
    }[op]
    return ir.Atom(f"x{i} {op} {c!r}", rob, sat)


# ---- naive semantics --------------------------------------------------------------------------

def naive(node, trace: np.ndarray, boolean: bool = False) -> list:
    """Values at every step of one trace ``[T, n]``: floats (robustness) or bools (satisfaction)."""
    T = trace.shape[0]
    bot, top = (False, True) if boolean else (-INF, INF)
    neg = (lambda v: not v) if boolean else (lambda v: -v)

    def ev(n):
        if isinstance(n, ir.Atom):
            f = n.satisfied if boolean else n.robustness
            return [bool(f(trace[t])) if boolean else float(f(trace[t])) for t in range(T)]
        if isinstance(n, ir.Const):
            return [top if n.value else bot] * T
        if isinstance(n, ir.Not):
            return [neg(v) for v in ev(n.arg)]
        if isinstance(n, (ir.And, ir.Or, ir.Implies)):
            a, b = ev(n.left), ev(n.right)
            if isinstance(n, ir.And):
                return [min(x, y) for x, y in zip(a, b)]
            if isinstance(n, ir.Or):
                return [max(x, y) for x, y in zip(a, b)]
            return [max(neg(x), y) for x, y in zip(a, b)]
        lo, hi = n.interval.lo, n.interval.hi
        hi_ = 10**9 if hi is None else hi
        if isinstance(n, (ir.Always, ir.Eventually, ir.Historically, ir.Once)):
            x = ev(n.arg)
            out = []
            for t in range(T):
                if isinstance(n, (ir.Always, ir.Eventually)):
                    idx = [k for k in range(t + lo, min(t + hi_, T - 1) + 1)]
                else:
                    idx = [k for k in range(max(t - hi_, 0), t - lo + 1)]
                vals = [x[k] for k in idx]
                if isinstance(n, (ir.Always, ir.Historically)):
                    out.append(min(vals, default=top))
                else:
                    out.append(max(vals, default=bot))
            return out
        phi, psi = ev(n.left), ev(n.right)
        out = []
        for t in range(T):
            best = bot
            if isinstance(n, ir.Until):
                for k in range(t + lo, min(t + hi_, T - 1) + 1):
                    best = max(best, min([psi[k]] + [phi[j] for j in range(t, k)]))
            else:
                for k in range(max(t - hi_, 0), t - lo + 1):
                    best = max(best, min([psi[k]] + [phi[j] for j in range(k + 1, t + 1)]))
            out.append(best)
        return out

    return ev(node)


# ---- strategies -------------------------------------------------------------------------------

N_VARS = 2
CONSTS = [-1.0, -0.5, 0.0, 0.5, 1.0]


@st.composite
def atoms(draw):
    return make_atom(draw(st.integers(0, N_VARS - 1)), draw(st.sampled_from(["<", "<=", ">", ">="])),
                     draw(st.sampled_from(CONSTS)))


@st.composite
def intervals(draw, unbounded_lo0_only: bool = False, allow_unbounded: bool = True):
    lo = draw(st.integers(0, 4))
    if allow_unbounded and draw(st.integers(0, 4)) == 0:
        return ir.Interval(0 if unbounded_lo0_only else lo, None)
    return ir.Interval(lo, lo + draw(st.integers(0, 4)))


UNARY = (ir.Always, ir.Eventually, ir.Historically, ir.Once)
BINARY_TEMPORAL = (ir.Until, ir.Since)


def formulas(*, causal: bool = False, rtamt: bool = False, consts: bool = True, max_leaves: int = 6):
    """Random formulas over every operator (``causal``: past operators only)."""
    leaf = atoms() if (rtamt or not consts) else st.one_of(atoms(), atoms(), st.builds(ir.Const, st.booleans()))
    un_ops = (ir.Historically, ir.Once) if causal else UNARY
    bin_ops = (ir.Since,) if causal else BINARY_TEMPORAL
    itv = intervals(unbounded_lo0_only=rtamt)

    def extend(children):
        return st.one_of(
            st.builds(ir.Not, children),
            st.builds(ir.And, children, children),
            st.builds(ir.Or, children, children),
            st.builds(ir.Implies, children, children),
            st.builds(lambda op, i, a: op(i, a), st.sampled_from(un_ops), itv, children),
            st.builds(lambda op, i, a, b: op(i, a, b), st.sampled_from(bin_ops), itv, children, children),
        )

    return st.recursive(leaf, extend, max_leaves=max_leaves)


# Values on a coarse grid (ties and exact zeros are frequent) or arbitrary floats.
_grid = st.sampled_from([-1.5, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5])
_any = st.floats(-3, 3, allow_nan=False, allow_infinity=False)


@st.composite
def traces(draw, min_T: int = 1, max_T: int = 14, batch: int = 1):
    T = draw(st.integers(min_T, max_T))
    elems = draw(st.sampled_from([_grid, _any]))
    vals = draw(st.lists(elems, min_size=batch * T * N_VARS, max_size=batch * T * N_VARS))
    return np.array(vals, dtype=np.float64).reshape(batch, T, N_VARS)
