"""Robustness speed: asap_dsl offline/online evaluators against rtamt 0.4.10, side by side.

    python benchmarks/robustness.py            # B = 64, T = 10 000, windows 10 and 1000
    python benchmarks/robustness.py --quick    # smaller, for a smoke run

Offline: ``always[0,w](x < 1) and eventually[0,w](y > 0)`` on B traces of T steps. rtamt's offline
monitor handles one trace at a time and is slow, so it is timed on a few of the same traces and
its time scaled per trace (said in the output). Online: ``historically[0,w](x < 1) and
once[0,w](y > 0)``, our batched ``Monitor.update`` against rtamt's ``update`` on one trace; the
figure compared is the cost per step per trace. Every rtamt result is also checked for equality
with ours on the traces it ran on.
"""

from __future__ import annotations

import argparse
import logging
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from asap_dsl.stl import ir, offline, online  # noqa: E402

X_LT_1 = ir.Atom("x < 1", lambda s: 1.0 - s[..., 0], lambda s: s[..., 0] < 1.0)
Y_GT_0 = ir.Atom("y > 0", lambda s: s[..., 1], lambda s: s[..., 1] > 0.0)


def offline_formula(w):
    return ir.And(ir.Always(ir.Interval(0, w), X_LT_1), ir.Eventually(ir.Interval(0, w), Y_GT_0))


def online_formula(w):
    return ir.And(ir.Historically(ir.Interval(0, w), X_LT_1), ir.Once(ir.Interval(0, w), Y_GT_0))


def best_of(fn, repeat):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def rtamt_spec(kind, text):
    import rtamt

    spec = (rtamt.StlDiscreteTimeOfflineSpecification() if kind == "offline"
            else rtamt.StlDiscreteTimeOnlineSpecification())
    for v in ("x", "y", "out"):
        spec.declare_var(v, "float")
    spec.spec = "out = " + text
    spec.parse()
    return spec


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes, for a smoke run")
    args = ap.parse_args(argv)
    logging.disable(logging.WARNING)  # rtamt's implicit-declaration warnings
    try:
        import rtamt  # noqa: F401
    except ImportError:
        sys.exit("rtamt is needed for the comparison: pip install rtamt==0.4.10")

    B, T = (64, 2000) if args.quick else (64, 10_000)
    n_rt = 1 if args.quick else 2            # traces rtamt's offline monitor is timed on
    T_on = 1200 if args.quick else 3000      # online steps (> 2 windows: steady state)
    rt_on_steps = 1200 if args.quick else 3000
    windows = (10, 1000)
    rng = np.random.default_rng(0)
    traces = rng.normal(size=(B, T, 2))
    print(f"asap_dsl STL robustness vs rtamt {rtamt_version()} -- B = {B} traces, T = {T} steps, "
          f"windows {windows}")
    print(f"(rtamt offline timed on {n_rt} of the same traces and scaled per trace; online costs "
          f"per step per trace, ours over {T_on} steps x {B} traces, rtamt over {rt_on_steps} steps "
          f"x 1 trace)\n")

    rows = {}
    for w in windows:
        f = offline_formula(w)
        ours_t, ours = best_of(lambda: offline.robustness(f, traces), 3)
        spec = rtamt_spec("offline", f"(always[0,{w}](x < 1.0)) and (eventually[0,{w}](y > 0.0))")
        rt_total, maxdiff = 0.0, 0.0
        for b in range(n_rt):
            data = {"time": list(range(T)), "x": traces[b, :, 0].tolist(), "y": traces[b, :, 1].tolist()}
            t0 = time.perf_counter()
            res = spec.evaluate(data)
            rt_total += time.perf_counter() - t0
            theirs = np.array([v for _, v in res])
            maxdiff = max(maxdiff, float(np.max(np.abs(theirs - ours[b]))))
        rt_per_trace = rt_total / n_rt
        ours_per_trace = ours_t / B

        g = online_formula(w)

        def run_ours(sat):
            mon = online.Monitor(g, B, satisfaction=sat)
            out = np.empty((T_on, B))
            for t in range(T_on):
                out[t] = mon.update(traces[:, t])
            return out

        on_t, on_out = best_of(lambda: run_ours(False), 2)
        on_sat_t, _ = best_of(lambda: run_ours(True), 1)
        spec_on = rtamt_spec("online", f"(historically[0,{w}](x < 1.0)) and (once[0,{w}](y > 0.0))")
        xs, ys = traces[0, :, 0].tolist(), traces[0, :, 1].tolist()
        t0 = time.perf_counter()
        rt_on = [spec_on.update(i, [("x", xs[i]), ("y", ys[i])]) for i in range(rt_on_steps)]
        rt_on_t = time.perf_counter() - t0
        on_diff = float(np.max(np.abs(np.array(rt_on) - on_out[:rt_on_steps, 0])))
        rows[w] = dict(
            off_ours=ours_per_trace, off_rt=rt_per_trace, off_batch=ours_t, off_diff=maxdiff,
            on_ours=on_t / (T_on * B), on_ours_sat=on_sat_t / (T_on * B), on_rt=rt_on_t / rt_on_steps,
            on_step=on_t / T_on, on_diff=on_diff,
        )

    us = 1e6
    print(f"{'':34s}" + "".join(f"{'w = ' + str(w):>16s}" for w in windows))
    line = lambda label, key, scale=us, fmt="{:16.3f}": print(  # noqa: E731
        f"{label:34s}" + "".join(fmt.format(rows[w][key] * scale) for w in windows))
    print("offline, per trace of T steps")
    line("  asap_dsl (batched)         ms", "off_ours", 1e3)
    line("  rtamt                      ms", "off_rt", 1e3)
    line("  asap_dsl whole batch       ms", "off_batch", 1e3)
    line("  max |ours - rtamt|", "off_diff", 1.0, "{:16.1e}")
    print("online, per step per trace")
    line("  asap_dsl Monitor           us", "on_ours")
    line("  asap_dsl (+ satisfaction)  us", "on_ours_sat")
    line("  rtamt update               us", "on_rt")
    line("  asap_dsl per batch step    us", "on_step")
    line("  max |ours - rtamt|", "on_diff", 1.0, "{:16.1e}")
    print("\nratios")
    for w in windows:
        r = rows[w]
        print(f"  w = {w:<5d} offline speed-up over rtamt: {r['off_rt'] / r['off_ours']:8.0f}x  (target >= 100x)")
        print(f"  w = {w:<5d} online speed-up over rtamt:  {r['on_rt'] / r['on_ours']:8.1f}x  (target >= 20x)"
              f"   [{r['on_rt'] / r['on_ours_sat']:.1f}x with satisfaction tracked too]")
    a, b = windows
    print(f"  our cost, w = {b} over w = {a}: offline {rows[b]['off_ours'] / rows[a]['off_ours']:.2f}x, "
          f"online {rows[b]['on_ours'] / rows[a]['on_ours']:.2f}x  (target <= 2x)")
    print(f"  rtamt's,  w = {b} over w = {a}: offline {rows[b]['off_rt'] / rows[a]['off_rt']:.1f}x, "
          f"online {rows[b]['on_rt'] / rows[a]['on_rt']:.1f}x")
    batch_one(traces, 1000 if args.quick else 3000)


# The formulas of the batch-1 comparison, written in the language (so that the atoms have the
# scalar forms a spec gives them): (label, windows of historically and once, target or None).
BATCH_ONE = [("w = 10", 10, 10, None), ("w = 100", 100, 100, 20.0), ("w = 1000", 1000, 1000, 20.0),
             ("w = 100 and 1000", 100, 1000, 20.0)]


def batch_one(traces, steps):
    """One trace, one update per step (a single environment): ``monitor_for(node, 1)`` (the
    scalar monitor) and, for reference, the batched Monitor at B = 1, against rtamt's update;
    the best of three runs on each side."""
    import asap_dsl

    print(f"\nonline, ONE trace (batch 1, one update per step, {steps} steps), per update:")
    print(f"  {'formula':<18s} {'asap_dsl':>10s} {'(+ sat.)':>10s} {'batched B=1':>12s} {'rtamt':>10s} {'ratio':>9s}")
    xs, ys = traces[0, :, 0].tolist(), traces[0, :, 1].tolist()
    states = traces[0, :steps, None, :].copy()
    for label, wh, wo, target in BATCH_ONE:
        prog = asap_dsl.loads(f"system Plane {{\n state x in [-1e9, 1e9]\n state y in [-1e9, 1e9]\n action u in [-1, 1]\n"
                              f" dt = 1\n map {{ x = x + u, y = y + u }}\n}}\n"
                              f"task t {{ asap historically[0, {wh}] x < 1 and once[0, {wo}] y > 0  deadline 5000 }}\n")
        node = prog.task("t").model.asap

        def run(mon):
            t0 = time.perf_counter()
            out = [mon.update(states[k])[0] for k in range(steps)]
            return (time.perf_counter() - t0) / steps, out

        ours, out = min((run(online.monitor_for(node, 1, satisfaction=False)) for _ in range(3)), key=lambda r: r[0])
        ours_sat, _ = run(online.monitor_for(node, 1))
        batched, _ = run(online.Monitor(node, 1, satisfaction=False))
        def run_rtamt():
            spec = rtamt_spec("online", f"(historically[0,{wh}](x < 1.0)) and (once[0,{wo}](y > 0.0))")
            t0 = time.perf_counter()
            rt = [spec.update(i, [("x", xs[i]), ("y", ys[i])]) for i in range(steps)]
            return (time.perf_counter() - t0) / steps, rt

        rt_t, rt = min((run_rtamt() for _ in range(3)), key=lambda r: r[0])  # best of 3, as ours
        assert np.array_equal(np.array(rt), np.array(out)), f"{label}: rtamt and asap_dsl disagree"
        ratio = rt_t / ours
        verdict = "" if target is None else f"  ({'PASS' if ratio >= target else 'FAIL'}, target >= {target:g}x)"
        print(f"  {label:<18s} {ours * 1e6:8.2f}us {ours_sat * 1e6:8.2f}us {batched * 1e6:10.2f}us "
              f"{rt_t * 1e6:8.2f}us {ratio:8.1f}x{verdict}")


def rtamt_version():
    try:
        from importlib.metadata import version

        return version("rtamt")
    except Exception:  # pragma: no cover
        return "?"


if __name__ == "__main__":
    main()
