"""Our offline robustness agrees with rtamt 0.4.10's discrete-time offline monitor.

Random formulas over every operator (atoms ``x_i <op> c``; not, and, or, implies; always,
eventually, historically, once, until, since with bounded intervals including ``[a, a]`` and
``[0, 0]``, and unbounded ones where rtamt has them, i.e. the untimed ``[0, inf)`` forms) on
random traces. The comparison is made at *every* step, not only where the windows fit inside the
trace: the cut-window convention and the strict until/since are rtamt's too. A separate check
restricted to the steps whose windows fit (``ir.horizon``/``ir.history``) is kept, as LANGUAGE.md
states it that way. ``ASAP_FUZZ_EXAMPLES=N`` raises the number of examples.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings

from asap_dsl.stl import ir, offline
from stl_reference import N_VARS, examples, formulas, traces

rtamt = pytest.importorskip("rtamt")
logging.getLogger().setLevel(logging.ERROR)  # rtamt warns about the implicit output variable


def to_rtamt(node) -> str:
    if isinstance(node, ir.Atom):
        return f"({node.text})"
    if isinstance(node, ir.Not):
        return f"(not {to_rtamt(node.arg)})"
    if isinstance(node, (ir.And, ir.Or, ir.Implies)):
        op = {ir.And: "and", ir.Or: "or", ir.Implies: "->"}[type(node)]
        return f"({to_rtamt(node.left)} {op} {to_rtamt(node.right)})"
    itv = node.interval
    if itv.hi is None:
        assert itv.lo == 0, "rtamt has unbounded operators only as [0, inf)"
        bounds = ""
    else:
        bounds = f"[{itv.lo},{itv.hi}]"
    name = type(node).__name__.lower()
    if isinstance(node, ir.UNARY_TEMPORAL):
        return f"({name}{bounds}{to_rtamt(node.arg)})"
    return f"({to_rtamt(node.left)} {name}{bounds} {to_rtamt(node.right)})"


def rtamt_robustness(node, trace: np.ndarray) -> np.ndarray:
    spec = rtamt.StlDiscreteTimeOfflineSpecification()
    for i in range(N_VARS):
        spec.declare_var(f"x{i}", "float")
    spec.declare_var("out", "float")
    spec.spec = "out = " + to_rtamt(node)
    spec.parse()
    data = {"time": list(range(trace.shape[0]))}
    for i in range(N_VARS):
        data[f"x{i}"] = [float(v) for v in trace[:, i]]
    return np.array([v for _, v in spec.evaluate(data)], dtype=np.float64)


def close(a, b, tol=1e-9):
    with np.errstate(invalid="ignore"):
        return (a == b) | (np.abs(a - b) <= tol)


FUZZ = settings(max_examples=examples(150), deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@FUZZ
@given(formulas(rtamt=True), traces(min_T=2, max_T=12))  # rtamt 0.4.10 crashes on T = 1
def test_agrees_with_rtamt_at_every_step(node, trace):
    ours = offline.robustness(node, trace[0])
    theirs = rtamt_robustness(node, trace[0])
    ok = close(ours, theirs)
    assert ok.all(), (
        f"{ir.to_text(node)}\nsteps {np.flatnonzero(~ok)}\nours   {ours}\nrtamt  {theirs}"
    )


@settings(FUZZ, max_examples=examples(60))
@given(formulas(rtamt=True, max_leaves=4), traces(min_T=10, max_T=16))
def test_agrees_with_rtamt_where_windows_fit(node, trace):
    T = trace.shape[1]
    fut, past = ir.horizon(node), ir.history(node)
    steps = [t for t in range(T) if t + fut <= T - 1 and t - past >= 0]
    ours = offline.robustness(node, trace[0])[steps]
    theirs = rtamt_robustness(node, trace[0])[steps]
    assert close(ours, theirs).all(), ir.to_text(node)


@pytest.mark.parametrize("text,node", [
    ("until", ir.Until(ir.Interval(1, 2), "L", "R")),
    ("since", ir.Since(ir.Interval(0, 2), "L", "R")),
    ("until-unbounded", ir.Until(ir.Interval(0, None), "L", "R")),
    ("since-unbounded", ir.Since(ir.Interval(0, None), "L", "R")),
])
def test_strictness_matches_rtamt(text, node):
    """A trace where strict and non-strict until/since differ: φ fails exactly where ψ holds."""
    from stl_reference import make_atom
    phi, psi = make_atom(0, ">", 0.0), make_atom(1, ">", 0.0)
    node = type(node)(node.interval, phi, psi)
    # x0 (φ) is -1 exactly when x1 (ψ) is +1: the non-strict reading would be negative there.
    x1 = np.array([-1.0, -2.0, 1.0, -1.0, 2.0, -3.0, 1.0])
    x0 = np.where(x1 > 0, -1.0, 2.0)
    trace = np.stack([x0, x1], axis=1)
    ours, theirs = offline.robustness(node, trace), rtamt_robustness(node, trace)
    assert close(ours, theirs).all(), (text, ours, theirs)
    assert (ours > 0).any(), "the strict reading must see a positive margin here"
