"""Training engines side by side: sbx (JAX) against stable-baselines3 (torch) on one task.

Each engine trains the same run (the default preset's settings for the algorithm, seed 0, no final
evaluation, all its steps: the plateau rule off, so that every variant trains as many) in a fresh
process of its own, one after the other: the wall time of the training, its CPU time (above the
wall time: more than one core; on a busy machine the steadier figure), its environment steps per
second (without the oracle's demonstrations unless ``--demonstrations``: their search is not
environment steps, and the default as issue 16 found it had none), and then the cost of one
gradient step alone (the run's checkpointed model and replay buffer, ``--grad-steps`` steps after a
warm-up, best of three blocks). Prints the ratios.

    .venv/bin/python benchmarks/engines.py [--spec specs/dc_motor.asap] [--task reach_avoid]
        [--algo sac] [--steps 50000] [--variants sbx,sb3] [--grad-steps 1000] [--demonstrations 0]

A variant is an engine, optionally with its threads: ``sbx`` (one XLA compute thread, what the
engine sets), ``sbx:eigen`` (XLA's multi-threaded default), ``sb3`` (torch's default threads),
``sb3:1`` (one torch thread, as a sweep's workers run); and optionally the environment step after
an ``@``: ``sb3@numpy`` (torch, the numpy step). ``before16`` is the default as issue 16 found it:
torch, the numpy step and one gradient step after every vector step, e.g.

    .venv/bin/python benchmarks/engines.py --spec specs/attitude.asap --steps 250000 --variants sbx,before16
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _child(args) -> dict:
    """One variant's training and gradient-step timing, in this (fresh) process."""
    from dataclasses import replace

    from asap_dsl.backends.rl import presets

    presets.PRESETS["default"] = replace(presets.DEFAULT, plateau=None)  # every variant trains all its steps
    settings = None
    variant, _, step = args.child.partition("@")
    if variant == "before16":
        from train import BEFORE16_SETTINGS  # benchmarks/train.py: the one definition of that variant

        variant, step, settings = "sb3", "numpy", BEFORE16_SETTINGS
    engine, _, threads = variant.partition(":")
    if step:
        os.environ["ASAP_ENGINE"] = step  # make_vec_env's step: native, numpy or auto
    if threads == "eigen":
        os.environ["XLA_FLAGS"] = "--xla_cpu_multi_thread_eigen=true"  # the engine leaves an explicit choice alone
    if threads.isdigit():
        import torch

        torch.set_num_threads(int(threads))
    import asap_dsl
    from asap_dsl.backends.rl.engines import get_engine

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        cpu0, wall0 = time.process_time(), time.perf_counter()
        res = asap_dsl.train(args.spec, args.task, algo=args.algo, engine=engine, steps=args.steps, seed=0, out=out,
                             evaluate=False, demonstrations=args.demonstrations, settings=settings)
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        row = {"variant": args.child, "steps": res.steps, "wall": wall, "cpu": cpu, "training": res.seconds,
               "validations": len(res.curves)}
        if args.algo in ("sac", "td3", "ddpg"):
            row["grad_ms"], row["grad_cpu_ms"] = _gradient_step_ms(get_engine(engine), args.algo, out / "checkpoint",
                                                                   res.config.hyper, args.grad_steps)
    return row


def _gradient_step_ms(engine, algo: str, ckpt: Path, hyper: dict, n: int) -> tuple[float, float]:
    from stable_baselines3.common.logger import configure

    model = engine.load(algo, ckpt / "model.zip")
    model.load_replay_buffer(str(ckpt / "replay.pkl"))
    model.set_logger(configure(None, []))
    batch = int(hyper["batch_size"])
    k = max(1, int(hyper.get("gradient_steps", 1)))  # gradient steps per call, as the loop makes them
    model.train(gradient_steps=k, batch_size=batch)  # compiles (sbx)
    calls = max(1, n // k)
    wall = cpu = float("inf")
    for _ in range(3):
        t, c = time.perf_counter(), time.process_time()
        for _ in range(calls):
            model.train(gradient_steps=k, batch_size=batch)
        wall = min(wall, (time.perf_counter() - t) / (calls * k))
        cpu = min(cpu, (time.process_time() - c) / (calls * k))
    return 1e3 * wall, 1e3 * cpu


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", default=str(ROOT / "specs" / "dc_motor.asap"))
    ap.add_argument("--task", default="reach_avoid")
    ap.add_argument("--algo", default="sac")
    ap.add_argument("--steps", type=int, default=50_000)
    ap.add_argument("--variants", default="sbx,sb3")
    ap.add_argument("--grad-steps", type=int, default=1000, help="gradient steps per timing block")
    ap.add_argument("--demonstrations", type=int, default=0,
                    help="the oracle's demonstrations for off-policy runs (default 0: the learner's speed alone)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(_child(args)))
        return 0
    print(f"engines: {Path(args.spec).name} {args.task}, {args.algo}, default preset, {args.steps:,} steps, "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} at the start", flush=True)
    rows = []
    for variant in args.variants.split(","):
        cmd = [sys.executable, __file__, "--child", variant, "--spec", args.spec, "--task", args.task, "--algo",
               args.algo, "--steps", str(args.steps), "--grad-steps", str(args.grad_steps),
               "--demonstrations", str(args.demonstrations)]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            print(f"{variant}: failed\n{r.stderr[-2000:]}", file=sys.stderr)
            return 1
        row = json.loads(r.stdout.strip().splitlines()[-1])
        rows.append(row)
        grad = (f"; a gradient step {row['grad_ms']:.2f} ms ({row['grad_cpu_ms']:.2f} ms CPU)"
                if "grad_ms" in row else "")
        print(f"  {variant:<10} {row['wall']:7.1f} s ({row['cpu']:.1f} s CPU) for {row['steps']:,} steps, "
              f"{row['validations']} validations, {row['steps'] / row['wall']:,.0f} steps/s{grad}", flush=True)
    base = rows[-1]
    for row in rows[:-1]:
        text = (f"{base['variant']} / {row['variant']}: wall {base['wall'] / row['wall']:.2f}x, "
                f"CPU {base['cpu'] / row['cpu']:.2f}x")
        if "grad_ms" in row:
            text += (f"; gradient step wall {base['grad_ms'] / row['grad_ms']:.2f}x, "
                     f"CPU {base['grad_cpu_ms'] / row['grad_cpu_ms']:.2f}x")
        print(text)
    print(f"load average {os.getloadavg()[0]:.2f} at the end (other work on the machine inflates every time)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
