"""Offline STL semantics: against the naive definitions, hand-computed cases, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings

from asap_dsl.stl import ir, offline
from stl_reference import examples, formulas, make_atom, naive, traces

INF = np.inf
FUZZ = settings(max_examples=examples(200), deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

X_LT_1 = make_atom(0, "<", 1.0)    # ρ = 1 - x0
X_GT_0 = make_atom(0, ">", 0.0)    # ρ = x0
Y_GT_0 = make_atom(1, ">", 0.0)    # ρ = x1


def tr(x0, x1=None):
    x0 = np.asarray(x0, dtype=float)
    x1 = np.zeros_like(x0) if x1 is None else np.asarray(x1, dtype=float)
    return np.stack([x0, x1], axis=-1)


# ---- against the naive definitions ---------------------------------------------------------

@FUZZ
@given(formulas(), traces(batch=3))
def test_robustness_and_satisfaction_equal_the_definitions(node, batch):
    rob = offline.robustness(node, batch)
    sat = offline.satisfied(node, batch)
    assert rob.shape == sat.shape == batch.shape[:2]
    assert rob.dtype == np.float64 and sat.dtype == np.bool_
    for b in range(batch.shape[0]):
        assert np.array_equal(rob[b], naive(node, batch[b])), ir.to_text(node)
        assert np.array_equal(sat[b], naive(node, batch[b], boolean=True)), ir.to_text(node)


@FUZZ
@given(formulas(), traces(batch=2))
def test_sign_of_robustness_agrees_with_satisfaction(node, batch):
    rob = offline.robustness(node, batch)
    sat = offline.satisfied(node, batch)
    assert np.all(sat[rob > 0])
    assert not np.any(sat[rob < 0])


@FUZZ
@given(formulas(), traces(batch=2))
def test_first_time(node, batch):
    sat = offline.satisfied(node, batch)
    ft = offline.first_time(node, batch)
    assert ft.shape == (2,)
    for b in range(2):
        hits = np.flatnonzero(sat[b])
        assert ft[b] == (hits[0] if hits.size else INF)
    single = offline.first_time(node, batch[0])
    assert np.ndim(single) == 0 and single == ft[0]


def test_long_and_huge_windows_are_exact():
    rng = np.random.default_rng(1)
    batch = rng.normal(size=(3, 300, 2))
    for node in [ir.Always(ir.Interval(3, 40), X_LT_1), ir.Once(ir.Interval(0, 10**9), Y_GT_0),
                 ir.Until(ir.Interval(5, 97), X_LT_1, Y_GT_0),
                 ir.Since(ir.Interval(2, 299), X_LT_1, Y_GT_0),
                 ir.Eventually(ir.Interval(7, None), X_GT_0)]:
        rob = offline.robustness(node, batch)
        for b in range(3):
            assert np.array_equal(rob[b], naive(node, batch[b])), ir.to_text(node)


# ---- end of trace, hand-computed -----------------------------------------------------------

def test_eventually_near_the_end_of_the_trace():
    # ρ(x0 > 0) = x0; eventually[0,5] at t is the max over [t, min(t+5, T-1)].
    x0 = [0.0, -1.0, 3.0, -2.0, -4.0, 1.0, -5.0, -6.0]
    rob = offline.robustness(ir.Eventually(ir.Interval(0, 5), X_GT_0), tr(x0))
    assert rob.tolist() == [3.0, 3.0, 3.0, 1.0, 1.0, 1.0, -5.0, -6.0]
    # eventually[2,5]: the window [t+2, t+5] is empty for t >= T-2 -> -inf.
    rob = offline.robustness(ir.Eventually(ir.Interval(2, 5), X_GT_0), tr(x0))
    assert rob.tolist() == [3.0, 1.0, 1.0, 1.0, -5.0, -6.0, -INF, -INF]
    assert offline.satisfied(ir.Eventually(ir.Interval(2, 5), X_GT_0), tr(x0)).tolist()[-2:] == [False, False]
    rob = offline.robustness(ir.Always(ir.Interval(2, 5), X_GT_0), tr(x0))
    assert rob.tolist() == [-4.0, -5.0, -6.0, -6.0, -6.0, -6.0, INF, INF]
    assert offline.satisfied(ir.Always(ir.Interval(2, 5), X_GT_0), tr(x0)).tolist()[-2:] == [True, True]


def test_past_windows_at_the_start_of_the_trace():
    x0 = [5.0, -1.0, 2.0, 7.0, -3.0, 0.5]
    hist = offline.robustness(ir.Historically(ir.Interval(2, 4), X_GT_0), tr(x0))
    assert hist.tolist() == [INF, INF, 5.0, -1.0, -1.0, -1.0]
    once = offline.robustness(ir.Once(ir.Interval(2, 4), X_GT_0), tr(x0))
    assert once.tolist() == [-INF, -INF, 5.0, 5.0, 5.0, 7.0]
    assert offline.satisfied(ir.Historically(ir.Interval(2, 4), X_GT_0), tr(x0)).tolist() == \
        [True, True, True, False, False, False]
    assert offline.satisfied(ir.Once(ir.Interval(2, 4), X_GT_0), tr(x0)).tolist() == \
        [False, False, True, True, True, True]


def test_until_and_since_hand_computed():
    # φ: ρ = x0, ψ: ρ = x1.
    x0 = [2.0, 1.0, -1.0, 3.0, 4.0]
    x1 = [-5.0, -2.0, 6.0, -1.0, 0.5]
    until = ir.Until(ir.Interval(1, 2), X_GT_0, Y_GT_0)
    # t=0: t'=1: min(-2, φ0=2) = -2; t'=2: min(6, 2, 1) = 1 -> 1
    # t=1: t'=2: min(6, 1) = 1;      t'=3: min(-1, 1, -1) = -1 -> 1
    # t=2: t'=3: min(-1, -1) = -1;   t'=4: min(0.5, -1, 3) = -1 -> -1
    # t=3: t'=4: min(0.5, 3) = 0.5 -> 0.5;  t=4: empty -> -inf
    assert offline.robustness(until, tr(x0, x1)).tolist() == [1.0, 1.0, -1.0, 0.5, -INF]
    # Strict: φ need not hold where ψ holds (x0 = -1 at t=2 does not matter for t'=2).
    strict = ir.Until(ir.Interval(0, None), X_GT_0, Y_GT_0)
    # t=2: ψ(2) = 6 directly; t=1: max(-2, min(6, φ1=1)) = 1; t=0: max(-5, min(-2, 2), min(6, 2, 1)) = 1
    assert offline.robustness(strict, tr(x0, x1)).tolist()[:3] == [1.0, 1.0, 6.0]
    since = ir.Since(ir.Interval(1, 3), X_GT_0, Y_GT_0)
    # t=0: empty -> -inf; t=1: t'=0: min(-5, φ1=1) = -5
    # t=2: t'=1: min(-2, φ2=-1) = -2; t'=0: min(-5, 1, -1) = -5 -> -2
    # t=3: t'=2: min(6, φ3=3) = 3; t'=1: min(-2, -1, 3) = -2; t'=0: -5 -> 3
    # t=4: t'=3: min(-1, 4) = -1; t'=2: min(6, 3, 4) = 3; t'=1: min(-2, ...) -> 3
    assert offline.robustness(since, tr(x0, x1)).tolist() == [-INF, -5.0, -2.0, 3.0, 3.0]
    assert offline.satisfied(since, tr(x0, x1)).tolist() == [False, False, False, True, True]


def test_constants_and_implies():
    t = tr([0.5, 2.0])
    assert offline.robustness(ir.Const(True), t).tolist() == [INF, INF]
    assert offline.robustness(ir.Not(ir.Const(True)), t).tolist() == [-INF, -INF]
    imp = ir.Implies(X_LT_1, Y_GT_0)  # max(-(1 - x0), x1) with x1 = 0
    assert offline.robustness(imp, t).tolist() == [0.0, 1.0]
    assert offline.satisfied(imp, t).tolist() == [False, True]


def test_exact_comparisons_in_satisfaction():
    le, lt = make_atom(0, "<=", 1.0), make_atom(0, "<", 1.0)
    t = tr([1.0])
    assert offline.robustness(le, t).tolist() == offline.robustness(lt, t).tolist() == [0.0]
    assert offline.satisfied(le, t).tolist() == [True]
    assert offline.satisfied(lt, t).tolist() == [False]


def test_shared_subformula_evaluated_once():
    calls = []
    atom = ir.Atom("x0 > 0", lambda s: (calls.append(1), s[..., 0])[1], lambda s: s[..., 0] > 0)
    f = ir.And(ir.Eventually(ir.Interval(0, 2), atom), ir.Always(ir.Interval(0, 3), atom))
    offline.robustness(f, tr([1.0, 2.0, 3.0]))
    assert len(calls) == 1


def test_result_does_not_alias_the_input():
    atom = ir.Atom("x0", lambda s: s[..., 0], lambda s: s[..., 0] > 0)
    t = tr([1.0, 2.0])
    out = offline.robustness(atom, t)
    out[0] = 99.0
    assert t[0, 0] == 1.0


# ---- bad input -----------------------------------------------------------------------------

@pytest.mark.parametrize("bad,msg", [
    (np.zeros(5), "shape"),
    (np.zeros((1, 2, 3, 2)), "shape"),
    (np.zeros((0, 2)), "at least one step"),
    (np.zeros((2, 0, 2)), "at least one step"),
    ([["a", "b"]], "numeric"),
])
def test_bad_shapes(bad, msg):
    with pytest.raises(ValueError, match=msg):
        offline.robustness(X_LT_1, bad)


def test_nan_and_inf_name_the_batch_index_and_step():
    t = np.zeros((3, 4, 2))
    t[2, 1, 0] = np.nan
    with pytest.raises(ValueError, match=r"batch index 2, step 1"):
        offline.robustness(X_LT_1, t)
    t = np.zeros((4, 2))
    t[3, 1] = np.inf
    with pytest.raises(ValueError, match=r"step 3"):
        offline.satisfied(X_LT_1, t)


def test_state_dimension_checked_when_given():
    with pytest.raises(ValueError, match="expected 3"):
        offline.robustness(X_LT_1, np.zeros((4, 2)), n_state=3)
    assert offline.robustness(X_LT_1, np.zeros((4, 2)), n_state=2).shape == (4,)


def test_atom_with_wrong_output_shape():
    bad = ir.Atom("bad", lambda s: np.zeros(3), lambda s: np.zeros(3, bool))
    with pytest.raises(ValueError, match="bad"):
        offline.robustness(bad, np.zeros((2, 5, 2)))
