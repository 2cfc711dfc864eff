"""Online monitors equal the offline evaluator at every step, with per-entry resets."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from asap_dsl.stl import ir, offline, online
from stl_reference import atoms, examples, formulas, intervals, make_atom, traces

FUZZ = settings(max_examples=examples(150), deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

X_GT_0 = make_atom(0, ">", 0.0)
Y_GT_0 = make_atom(1, ">", 0.0)


def run_with_resets(mon, batch, resets, prefix: bool, node):
    """Feed ``batch [B, T, n]`` step by step, resetting entries where ``resets[:, t]`` is True
    before step t; compare with the offline evaluator on each entry's current segment."""
    B, T, _ = batch.shape
    seg_start = np.zeros(B, dtype=int)
    for t in range(T):
        if resets[:, t].any():
            mon.reset(resets[:, t])
            seg_start[resets[:, t]] = t
        out = mon.update(batch[:, t])
        assert out.dtype == np.float64 and out.shape == (B,)
        for b in range(B):
            seg = batch[b, seg_start[b] : t + 1]
            k = 0 if prefix else t - seg_start[b]
            want_r = offline.robustness(node, seg)[k]
            want_s = offline.satisfied(node, seg)[k]
            assert out[b] == want_r, (ir.to_text(node), b, t, out[b], want_r)
            assert mon.satisfied[b] == want_s, (ir.to_text(node), b, t)
            assert mon.t[b] == t - seg_start[b]


# ---- Monitor --------------------------------------------------------------------------------

@FUZZ
@given(formulas(causal=True), traces(batch=3, max_T=16))
def test_monitor_equals_offline_at_every_step(node, batch):
    B, T, _ = batch.shape
    mon = online.Monitor(node, B)
    rob, sat = offline.robustness(node, batch), offline.satisfied(node, batch)
    for t in range(T):
        assert np.array_equal(mon.update(batch[:, t]), rob[:, t]), (ir.to_text(node), t)
        assert np.array_equal(mon.satisfied, sat[:, t]), (ir.to_text(node), t)
        assert np.array_equal(mon.robustness, rob[:, t])


@FUZZ
@given(formulas(causal=True, max_leaves=4), traces(batch=3, min_T=4, max_T=20), st.data())
def test_monitor_with_per_entry_resets(node, batch, data):
    B, T, _ = batch.shape
    resets = np.array(data.draw(st.lists(st.booleans(), min_size=B * T, max_size=B * T))).reshape(B, T)
    resets &= np.random.default_rng(0).random((B, T)) < 0.3
    run_with_resets(online.Monitor(node, B), batch, resets, prefix=False, node=node)


def test_long_bounded_windows_and_resets():
    rng = np.random.default_rng(3)
    B, T = 4, 120
    batch = rng.normal(size=(B, T, 2))
    node = ir.And(ir.Historically(ir.Interval(3, 17), X_GT_0),
                  ir.Since(ir.Interval(2, 30), Y_GT_0, ir.Once(ir.Interval(5, None), X_GT_0)))
    resets = rng.random((B, T)) < 0.03
    run_with_resets(online.Monitor(node, B), batch, resets, prefix=False, node=node)


# ---- PrefixMonitor --------------------------------------------------------------------------

def bounded_intervals():
    return intervals(allow_unbounded=False)


@st.composite
def prefix_formulas(draw):
    causal = formulas(causal=True, max_leaves=3)
    leaf = st.one_of(
        st.builds(ir.Eventually, bounded_intervals(), causal),
        st.builds(ir.Always, bounded_intervals(), causal),
        st.builds(ir.Until, bounded_intervals(), causal, causal),
        st.builds(ir.Eventually, intervals(), atoms()),
        causal,
    )
    return draw(st.recursive(leaf, lambda c: st.one_of(
        st.builds(ir.And, c, c), st.builds(ir.Or, c, c), st.builds(ir.Not, c),
        st.builds(ir.Implies, c, c)), max_leaves=3))


@FUZZ
@given(prefix_formulas(), traces(batch=3, max_T=14), st.data())
def test_prefix_monitor_equals_offline_on_every_prefix(node, batch, data):
    B, T, _ = batch.shape
    resets = np.zeros((B, T), dtype=bool)
    if data.draw(st.booleans()):
        resets = np.random.default_rng(data.draw(st.integers(0, 99))).random((B, T)) < 0.2
    run_with_resets(online.PrefixMonitor(node, B), batch, resets, prefix=True, node=node)


def test_task_specification_rho():
    """The rho reward's formula: eventually[0, D] asap and always[0, D] not avoid."""
    D = 6
    asap = ir.Historically(ir.Interval(0, 1), X_GT_0)
    avoid = Y_GT_0
    spec = ir.And(ir.Eventually(ir.Interval(0, D), asap), ir.Always(ir.Interval(0, D), ir.Not(avoid)))
    mon = online.monitor_for(spec, 2)
    assert isinstance(mon, online.PrefixMonitor)
    x0 = np.array([[-3, -1, 2, 1, 4, -1, 5, 6, 7, 9], [-1, -1, -1, -1, -1, -1, -1, -1, -1, 8]], float)
    x1 = np.array([[-2, -3, -1, -4, -5, -6, -7, -8, 3, 9], [-1] * 10], float)
    batch = np.stack([x0, x1], axis=-1)
    got = np.array([mon.update(batch[:, t]) for t in range(10)]).T
    # Entry 0, by hand: asap ρ = min(x0[t-1], x0[t]); avoid ρ = x1, so not avoid = -x1.
    #   F part: max over t' <= min(t, D) of asap: -3, -3, -1, 1, 1, 1, 1 and frozen after D = 6.
    #   G part: min over t' <= min(t, D) of -x1: 2, 2, 1, 1, 1, 1, 1, then frozen.
    assert got[0].tolist() == [-3, -3, -1, 1, 1, 1, 1, 1, 1, 1]
    assert got[1].tolist() == [-1] * 10
    for t in range(10):
        assert np.array_equal(got[:, t], offline.robustness(spec, batch[:, : t + 1])[:, 0])


# ---- refusals and bad input -----------------------------------------------------------------

def test_future_formula_refused_by_monitor_naming_the_operator():
    f = ir.And(X_GT_0, ir.Eventually(ir.Interval(0, 3), Y_GT_0))
    with pytest.raises(ValueError, match=r"eventually\[0, 3\]"):
        online.Monitor(f, 2)


def test_nested_future_refused_by_prefix_monitor():
    f = ir.Eventually(ir.Interval(0, 3), ir.Always(ir.Interval(1, 2), X_GT_0))
    with pytest.raises(ValueError, match=r"always\[1, 2\]"):
        online.monitor_for(f, 2)
    g = ir.Once(ir.Interval(0, 3), ir.Eventually(ir.Interval(0, 1), X_GT_0))
    with pytest.raises(ValueError, match=r"eventually\[0, 1\].*once"):
        online.PrefixMonitor(g, 2)


def test_monitor_for_picks_the_right_class():
    assert type(online.monitor_for(ir.Once(ir.Interval(0, None), X_GT_0), 3)) is online.Monitor
    assert type(online.monitor_for(ir.Always(ir.Interval(0, 3), X_GT_0), 3)) is online.PrefixMonitor


def test_bad_states_and_masks():
    mon = online.Monitor(ir.Once(ir.Interval(0, 2), X_GT_0), 3, n_state=2)
    with pytest.raises(ValueError, match=r"shape \[3, n_state\]"):
        mon.update(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="expected 2"):
        mon.update(np.zeros((3, 4)))
    bad = np.zeros((3, 2))
    bad[1, 0] = np.nan
    with pytest.raises(ValueError, match="batch index 1"):
        mon.update(bad)
    with pytest.raises(ValueError, match="bool array"):
        mon.reset(np.array([1, 0, 1]))
    with pytest.raises(ValueError, match="positive integer"):
        online.Monitor(X_GT_0, 0)


def test_satisfaction_can_be_turned_off():
    mon = online.Monitor(X_GT_0, 2, satisfaction=False)
    assert mon.update(np.array([[1.0, 0.0], [-2.0, 0.0]])).tolist() == [1.0, -2.0]
    with pytest.raises(ValueError, match="satisfaction=False"):
        mon.satisfied


def test_reset_all_and_step_counters():
    mon = online.Monitor(ir.Historically(ir.Interval(0, None), X_GT_0), 2)
    assert mon.t.tolist() == [-1, -1]
    mon.update(np.array([[-5.0, 0], [1.0, 0]]))
    mon.update(np.array([[2.0, 0], [3.0, 0]]))
    assert mon.robustness.tolist() == [-5.0, 1.0] and mon.t.tolist() == [1, 1]
    mon.reset(np.array([True, False]))
    assert mon.update(np.array([[2.0, 0], [0.5, 0]])).tolist() == [2.0, 0.5]
    assert mon.t.tolist() == [0, 2]
    mon.reset()
    assert mon.update(np.array([[7.0, 0], [8.0, 0]])).tolist() == [7.0, 8.0]


# ---- masked updates -------------------------------------------------------------------------

def run_masked(mon, node, pool, masks, resets, prefix: bool):
    """Step ``mon`` with ``update(pool[:, k], mask=masks[k])`` (after ``reset(resets[k])``): entry b
    advances only where masked, taking its next own state from ``pool[b]``; compare every entry
    (advanced or not) with the offline evaluator on its own trace so far."""
    B, K = pool.shape[0], len(masks)
    traces = [[] for _ in range(B)]
    used = np.zeros(B, dtype=int)
    last_r, last_s = np.full(B, np.nan), np.zeros(B, dtype=bool)
    for k in range(K):
        if resets[k].any():
            mon.reset(resets[k])
            for b in np.flatnonzero(resets[k]):
                traces[b] = []
        m = masks[k]
        states = np.full((B, pool.shape[2]), np.nan)  # rows of entries that stay are ignored
        states[m] = pool[m, used[m]]
        out = mon.update(states, mask=m)
        for b in np.flatnonzero(m):
            traces[b].append(pool[b, used[b]])
        used[m] += 1
        assert out.dtype == np.float64 and out.shape == (B,)
        for b in range(B):
            if not traces[b]:
                continue
            tr = np.array(traces[b])
            i = 0 if prefix else len(tr) - 1
            if m[b]:
                last_r[b] = offline.robustness(node, tr)[i]
                last_s[b] = offline.satisfied(node, tr)[i]
            assert out[b] == last_r[b], (ir.to_text(node), b, k, out[b], last_r[b])
            assert mon.satisfied[b] == last_s[b], (ir.to_text(node), b, k)
            assert mon.t[b] == len(tr) - 1


def _masks_and_resets(data, B, K):
    seed = data.draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    p = data.draw(st.sampled_from([0.3, 0.6, 0.9, 1.0]))
    masks = rng.random((K, B)) < p
    masks[rng.random(K) < 0.2] = True  # some full updates in between
    resets = rng.random((K, B)) < data.draw(st.sampled_from([0.0, 0.1, 0.25]))
    return masks, resets


@FUZZ
@given(formulas(causal=True, max_leaves=4), traces(batch=4, min_T=6, max_T=24), st.data())
def test_masked_monitor_equals_offline_on_each_entry_trace(node, pool, data):
    B, K, _ = pool.shape
    masks, resets = _masks_and_resets(data, B, K)
    run_masked(online.Monitor(node, B), node, pool, masks, resets, prefix=False)


@FUZZ
@given(prefix_formulas(), traces(batch=3, min_T=4, max_T=16), st.data())
def test_masked_prefix_monitor_equals_offline(node, pool, data):
    B, K, _ = pool.shape
    masks, resets = _masks_and_resets(data, B, K)
    run_masked(online.PrefixMonitor(node, B), node, pool, masks, resets, prefix=True)


def test_masked_long_windows_and_autoreset_pattern():
    """Long windows; the vector-env pattern (full update, then reset(done) and update(s0, mask=done))
    keeps the monitor on its aligned fast path; arbitrary masks take it off and back on."""
    rng = np.random.default_rng(5)
    B, K = 5, 400
    pool = rng.normal(size=(B, K, 2))
    node = ir.And(ir.Historically(ir.Interval(3, 17), X_GT_0),
                  ir.Since(ir.Interval(2, 30), Y_GT_0, ir.Once(ir.Interval(5, None), X_GT_0)))
    masks = np.ones((K, B), dtype=bool)
    resets = np.zeros((K, B), dtype=bool)
    for k in range(1, K, 2):  # odd k: fresh starts of the entries that finished
        done = rng.random(B) < 0.08
        resets[k], masks[k] = done, done
    mon = online.Monitor(node, B)
    run_masked(mon, node, pool, masks[:200], resets[:200], prefix=False)
    assert mon._clock.aligned
    masks[200:260] = rng.random((60, B)) < 0.5  # arbitrary masks: the general path
    mon2 = online.Monitor(node, B, satisfaction=False)
    run_masked(online.Monitor(node, B), node, pool, masks, resets, prefix=False)
    for k in range(K):
        mon2.update(pool[:, k])
    mon2.update(pool[:, 0], mask=np.array([True, False, False, False, False]))
    assert not mon2._clock.aligned
    mon2.reset()
    assert mon2._clock.aligned


def test_masked_update_checks_and_all_false_mask():
    mon = online.Monitor(ir.Once(ir.Interval(0, 2), X_GT_0), 3)
    with pytest.raises(ValueError, match="bool array"):
        mon.update(np.zeros((3, 2)), mask=np.array([1, 0, 1]))
    bad = np.zeros((3, 2))
    bad[1, 0] = np.nan
    with pytest.raises(ValueError, match="batch index 1"):
        mon.update(bad, mask=np.array([False, True, False]))
    mon.update(bad, mask=np.array([True, False, True]))  # unmasked rows are ignored
    assert mon.t.tolist() == [0, -1, 0]
    before = mon.robustness.copy()
    out = mon.update(np.ones((3, 2)), mask=np.zeros(3, dtype=bool))
    assert np.array_equal(out, before, equal_nan=True) and mon.t.tolist() == [0, -1, 0]


# ---- update_and_restart (one atom evaluation per env step) ----------------------------------

@FUZZ
@given(st.one_of(formulas(causal=True, max_leaves=4), prefix_formulas()),
       traces(batch=3, min_T=3, max_T=16), st.data())
def test_update_and_restart_equals_separate_calls(node, pool, data):
    """``update_and_restart(s, done, c)`` == ``update(s)``, ``reset(done)``, ``update(c, mask=done)``
    (robustness, satisfaction, t; the reached values it returns too), and both equal the offline
    evaluator on each entry's own trace; also off the aligned path (arbitrary masked updates)."""
    B, K, _ = pool.shape
    cands = data.draw(traces(batch=B, min_T=K, max_T=K))
    sat = data.draw(st.booleans())
    rng = np.random.default_rng(data.draw(st.integers(0, 2**31 - 1)))
    p = data.draw(st.sampled_from([0.0, 0.2, 0.5, 1.0]))
    done = rng.random((K, B)) < p
    off = rng.random(K) < data.draw(st.sampled_from([0.0, 0.2]))  # steps with a partial update
    part = rng.random((K, B)) < 0.5
    one = online.monitor_for(node, B, satisfaction=sat)
    sep = online.monitor_for(node, B, satisfaction=sat)
    prefix = isinstance(one, online.PrefixMonitor)
    seg = [[] for _ in range(B)]

    def want(b):
        tr = np.array(seg[b])
        i = 0 if prefix else len(tr) - 1
        return offline.robustness(node, tr)[i], offline.satisfied(node, tr)[i]

    for mon in (one, sep):
        mon.update(pool[:, 0])
    for b in range(B):
        seg[b].append(pool[b, 0])
    for k in range(1, K):
        if off[k]:  # an arbitrary masked update, same on both
            m = part[k]
            for mon in (one, sep):
                mon.update(pool[:, k], mask=m)
            for b in np.flatnonzero(m):
                seg[b].append(pool[b, k])
            continue
        rho, s = one.update_and_restart(pool[:, k], done[k], cands[:, k])
        r_sep = sep.update(pool[:, k]).copy()
        s_sep = sep.satisfied.copy() if sat else None
        sep.reset(done[k])
        sep.update(cands[:, k], mask=done[k])
        assert np.array_equal(rho, r_sep), (ir.to_text(node), k)
        assert (s is None) == (not sat)
        if sat:
            assert np.array_equal(s, s_sep), (ir.to_text(node), k)
        for b in range(B):
            seg[b].append(pool[b, k])
            wr, ws = want(b)
            assert rho[b] == wr, (ir.to_text(node), b, k, rho[b], wr)
            if sat:
                assert s[b] == ws
            if done[k, b]:
                seg[b] = [cands[b, k]]
        assert np.array_equal(one.robustness, sep.robustness), (ir.to_text(node), k)
        assert np.array_equal(one.t, sep.t)
        if sat:
            assert np.array_equal(one.satisfied, sep.satisfied)
        for b in range(B):
            wr, ws = want(b)
            assert one.robustness[b] == wr, (ir.to_text(node), b, k, one.robustness[b], wr)
            if sat:
                assert one.satisfied[b] == ws


@FUZZ
@given(st.one_of(formulas(causal=True, max_leaves=4), prefix_formulas()),
       traces(batch=3, min_T=2, max_T=12), st.data())
def test_tracker_step_and_restart_equals_step_then_restart(node, pool, data):
    from asap_dsl.rewards import FormulaTracker

    B, K, n = pool.shape
    cands = data.draw(traces(batch=B, min_T=K, max_T=K))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**31 - 1)))
    done = rng.random((K, B)) < data.draw(st.sampled_from([0.0, 0.3, 1.0]))
    sat = data.draw(st.booleans())
    one = FormulaTracker(node, B, n, satisfaction=sat)
    sep = FormulaTracker(node, B, n, satisfaction=sat)
    one.restart_all(pool[:, 0])
    sep.restart_all(pool[:, 0])
    for k in range(1, K):
        one.step_and_restart(pool[:, k], done[k], cands[:, k])
        sep.step(pool[:, k])
        r, s = sep.rob.copy(), sep.sat.copy()
        assert np.array_equal(sep.step_rob, r)
        sep.restart(done[k], cands[:, k])
        assert np.array_equal(one.step_rob, r) and np.array_equal(one.step_sat, s), (ir.to_text(node), k)
        assert np.array_equal(one.rob, sep.rob) and np.array_equal(one.sat, sep.sat), (ir.to_text(node), k)


# ---- the batch-1 monitor --------------------------------------------------------------------

@FUZZ
@given(formulas(causal=True), traces(batch=1, max_T=16), st.data())
def test_scalar_monitor_equals_offline_at_every_step_with_resets(node, batch, data):
    from asap_dsl.stl.scalar import ScalarMonitor

    _, T, _ = batch.shape
    resets = np.array(data.draw(st.lists(st.booleans(), min_size=T, max_size=T))).reshape(1, T)
    resets &= np.random.default_rng(1).random((1, T)) < 0.25
    run_with_resets(ScalarMonitor(node), batch, resets, prefix=False, node=node)


def test_monitor_for_a_single_trace_is_the_scalar_monitor_with_the_same_values():
    from asap_dsl.stl.scalar import ScalarMonitor

    node = ir.And(ir.Historically(ir.Interval(0, 100), X_GT_0), ir.Once(ir.Interval(2, 1000), Y_GT_0))
    mon = online.monitor_for(node, 1)
    assert type(mon) is ScalarMonitor
    trace = np.random.default_rng(0).normal(size=(1, 1500, 2))
    want = offline.robustness(node, trace)[0]
    got = [mon.update(trace[:, t])[0] for t in range(1500)]
    assert np.array_equal(got, want)
    mon.update(trace[:, 0], mask=np.array([False]))  # a masked update leaves it as it was
    assert mon.t[0] == 1499 and mon.robustness[0] == want[-1]
    with pytest.raises(ValueError, match="non-finite"):
        mon.update(np.array([[np.nan, 0.0]]))


def test_scalar_forms_of_language_atoms_equal_the_vectorised_ones():
    import asap_dsl

    prog = asap_dsl.loads(
        "system S1 {\n  state x in [-5, 5]\n  state y in [-5, 5]\n  action u in [-1, 1]\n  let r = sqrt(x^2 + y^2)\n"
        "  dt = 0.1\n  ode { x' = u, y' = u }\n}\nregion ball1 = ball({r: 1}, 0.5)\nregion box1 = box(x in [0, 1], y in [-1, 1])\n"
        "task t { asap (in ball1 or in box1) and sin(x) * y < 0.3 and log(x + 6) > 0.1  deadline 10 }\n")
    atoms = [a for a in ir.operands(prog.task("t").model.asap) for a in (ir.operands(a) if isinstance(a, ir.Or) else [a])]
    states = np.random.default_rng(0).uniform(-5, 5, size=(500, 2))
    for atom in atoms:
        assert atom.scalar is not None
        rho, sat = atom.robustness(states), atom.satisfied(states)
        for k, s in enumerate(states):
            r, b = atom.scalar(tuple(s))
            assert r == pytest.approx(rho[k], rel=1e-12, abs=1e-12) and b == sat[k], atom.text
