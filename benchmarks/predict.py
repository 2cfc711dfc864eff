"""The exploration action of sbx's SAC: the engine's fused draw against sbx's own, in one run.

sbx draws a SAC exploration action in two compiled calls (split the key, then sample);
:mod:`asap_dsl.backends.rl.engines` fuses them into one. Both run on the same trained policy and
observations, interleaved, best of three blocks; the script also checks that they draw the same
actions and keys. Prints microseconds per call and the ratio.

    .venv/bin/python benchmarks/predict.py [--spec specs/attitude.asap] [--calls 2000]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", default=str(ROOT / "specs" / "attitude.asap"))
    ap.add_argument("--task", default="reach_avoid")
    ap.add_argument("--calls", type=int, default=2000)
    args = ap.parse_args()
    import asap_dsl
    from asap_dsl.backends.rl.engines import get_engine

    with tempfile.TemporaryDirectory() as tmp:
        res = asap_dsl.train(args.spec, args.task, steps=3000, seed=0, out=Path(tmp) / "run", evaluate=False,
                             engine="sbx")
        model = get_engine("sbx").load("sac", Path(tmp) / "run" / "model.zip")
    import jax.numpy as jnp
    from sbx.sac.policies import SACPolicy

    policy = model.policy
    obs = np.random.default_rng(0).uniform(-1, 1, (res.config.n_envs,) + model.observation_space.shape)
    obs = obs.astype(np.float32)
    fused = policy._predict
    plain = lambda o, deterministic=False: SACPolicy._predict(policy, o, deterministic)  # noqa: E731
    best = {"fused": np.inf, "sbx": np.inf}
    for _ in range(3):
        for name, f in (("fused", fused), ("sbx", plain)):
            policy._predict = f
            policy.predict(obs)
            t0 = time.perf_counter()
            for _ in range(args.calls):
                policy.predict(obs)
            best[name] = min(best[name], (time.perf_counter() - t0) / args.calls * 1e6)
    key = np.asarray(policy.key)
    policy._predict = fused
    a1, k1 = np.asarray(policy.predict(obs)[0]), np.asarray(policy.key)
    policy.key = jnp.asarray(key)
    policy._predict = plain
    a2, k2 = np.asarray(policy.predict(obs)[0]), np.asarray(policy.key)
    print(f"exploration action, {Path(args.spec).name}, {res.config.n_envs} envs: fused {best['fused']:.0f} us, "
          f"sbx {best['sbx']:.0f} us per call: {best['sbx'] / best['fused']:.2f}x; same actions and keys: "
          f"{np.array_equal(a1, a2) and np.array_equal(k1, k2)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
