"""How close a state-feedback network gets to the ceiling when it is fitted to the oracle's own
optimal paths (docs/training.md, "Imitating the oracle at scale"): the question under the last
points of bicycle and attitude is whether they are the learner's (SAC, the reward, exploration) or
the policy's, a smooth network's approximation of a minimum-time feedback law.

The oracle on ``--train`` initial states (seed 31337) gives its optimal paths; every (state,
action) pair along them is a label (a minimum-time path is optimal from each of its states). A
network of the default's kind (ReLU layers, tanh output scaled to the action bounds; ``--width``,
``--depth``) is fitted by mean squared error (Adam, cosine decay from 1e-3), then judged by the
batched rollout on ``--test`` other initial states (seed 4242; never the evaluation seed 2024 nor
the validation seed 7) beside the oracle's rates on them. ``--rounds K`` adds DAgger: each round
the policy runs from ``--per-round`` fresh initial states, the oracle solves from ``--per-path``
states it visited (before its reach or failure), their paths join the labels, and the fit goes on.

    .venv/bin/python benchmarks/imitation.py specs/bicycle.asap --task reach_avoid --train 4000 \\
        [--test 300] [--paths 1000] [--width 256] [--depth 2] [--bins 21] [--epochs 200] [--rounds 5] [--workers 2]

The oracle's paths are kept in ``--cache`` (a pickle per spec, task and counts; default under
``runs/imitation``), so that other fits of the same labels do not solve again.
"""

from __future__ import annotations

import argparse
import pickle
import time
from pathlib import Path

import numpy as np
import torch

import asap_dsl
from asap_dsl.backends.oracle import run
from asap_dsl.rollout import Evaluator
from asap_dsl.sampling import task_states

TRAIN_SEED, TEST_SEED, ROUND_SEED = 31337, 4242, 7000


def labels(results) -> tuple[np.ndarray, np.ndarray]:
    """(state, action) along every solved path."""
    xs, us = [], []
    for r in results:
        if r.actions is None or len(r.actions) == 0 or r.trajectory is None:
            continue
        x = np.asarray(r.trajectory)[:-1].reshape(-1, len(r.x0))
        xs.append(x)
        us.append(np.asarray(r.actions).reshape(len(x), -1))
    return np.concatenate(xs), np.concatenate(us)


class Policy:
    """An MLP from the standardised state to actions in the bounds (a controller of the rollout):
    a tanh output fitted by squared error, or with ``bins`` a categorical head per action (``bins``
    levels across the bounds, cross-entropy, the most likely level acted on), which cannot average
    two modes of the optimum into an action that is neither."""

    def __init__(self, n: int, m: int, width: int, depth: int, mean, std, low, high, bins: int = 0):
        layers: list = [torch.nn.Linear(n, width), torch.nn.ReLU()]
        for _ in range(depth - 1):
            layers += [torch.nn.Linear(width, width), torch.nn.ReLU()]
        head = [torch.nn.Linear(width, m * bins)] if bins else [torch.nn.Linear(width, m), torch.nn.Tanh()]
        self.net = torch.nn.Sequential(*layers, *head)
        self.m, self.bins = m, bins
        self.mean, self.std, self.low, self.high = mean, std, low, high

    def inputs(self, x: np.ndarray) -> torch.Tensor:
        return torch.tensor((x - self.mean) / self.std, dtype=torch.float32)

    def targets(self, u: np.ndarray) -> torch.Tensor:
        z = np.clip((u - self.low) / (self.high - self.low), 0.0, 1.0)  # 0..1 across the bounds
        if self.bins:
            return torch.tensor(np.rint(z * (self.bins - 1)), dtype=torch.int64)
        return torch.tensor(2 * z - 1, dtype=torch.float32)

    def loss(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        if self.bins:
            return torch.nn.functional.cross_entropy(self.net(x).reshape(-1, self.bins), u.reshape(-1))
        return ((self.net(x) - u) ** 2).mean()

    def fit(self, x: np.ndarray, u: np.ndarray, epochs: int, batch: int = 512) -> float:
        xt, ut = self.inputs(x), self.targets(u)
        opt = torch.optim.Adam(self.net.parameters(), 1e-3)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs * -(-len(xt) // batch), eta_min=1e-5)
        loss = torch.zeros(())
        for _ in range(epochs):
            perm = torch.randperm(len(xt))
            for i in range(0, len(xt), batch):
                j = perm[i:i + batch]
                loss = self.loss(xt[j], ut[j])
                opt.zero_grad()
                loss.backward()
                opt.step()
                sched.step()
        return float(loss.detach())

    def reset(self, states: np.ndarray) -> None:
        pass

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        with torch.no_grad():
            out = self.net(self.inputs(states)).numpy()
        z = out.reshape(len(states), self.m, self.bins).argmax(-1) / (self.bins - 1) if self.bins else (out + 1) / 2
        return self.low + z * (self.high - self.low)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spec")
    ap.add_argument("--task", required=True)
    ap.add_argument("--train", type=int, default=4000)
    ap.add_argument("--test", type=int, default=300)
    ap.add_argument("--paths", type=int, help="fit the first PATHS of the --train paths only (how the fit scales)")
    ap.add_argument("--width", type=int, default=256)
    ap.add_argument("--depth", type=int, default=2)
    ap.add_argument("--epochs", type=int, default=200)
    ap.add_argument("--bins", type=int, default=0, help="a categorical head of BINS levels per action (0: tanh)")
    ap.add_argument("--rounds", type=int, default=0)
    ap.add_argument("--per-round", type=int, default=300)
    ap.add_argument("--per-path", type=int, default=3)
    ap.add_argument("--round-epochs", type=int, default=60)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cache", default="runs/imitation")
    args = ap.parse_args()
    torch.manual_seed(0)
    torch.set_num_threads(1)
    prog = asap_dsl.load(args.spec)
    task = prog.task(args.task).model
    cache = Path(args.cache) / f"{Path(args.spec).stem}-{args.task}-{args.train}-{args.test}.pkl"
    if cache.exists():
        train, test = pickle.loads(cache.read_bytes())
    else:
        t0 = time.time()
        train = run(prog, args.task, episodes=args.train, seed=TRAIN_SEED, workers=args.workers).results
        test = run(prog, args.task, episodes=args.test, seed=TEST_SEED, workers=args.workers).results
        print(f"the oracle on {args.train} + {args.test} states: {time.time() - t0:.0f} s", flush=True)
        cache.parent.mkdir(parents=True, exist_ok=True)
        cache.with_suffix(".tmp").write_bytes(pickle.dumps((train, test)))
        cache.with_suffix(".tmp").replace(cache)
    x, u = labels(train[:args.paths])
    judge = Evaluator(prog, args.task, np.stack([r.x0 for r in test]))
    tols = sorted(task.tolerances, reverse=True)
    ceiling = {T: round(100 * float(np.mean([r.steps is not None and r.steps <= T for r in test])), 1) for T in tols}
    print(f"{len(x):,} labels from {len(train[:args.paths])} paths; the oracle on the {args.test} test states: {ceiling}", flush=True)
    system = judge.core.system
    policy = Policy(x.shape[1], u.shape[1], args.width, args.depth, x.mean(0), x.std(0) + 1e-6,
                    system.action_low, system.action_high, args.bins)

    def report(tag: str, t0: float) -> None:
        r = judge.run(policy)
        print(f"{tag}: {({T: round(100 * r.rate(T), 1) for T in tols})} ({len(x):,} labels, {time.time() - t0:.0f} s)",
              flush=True)

    t0 = time.time()
    policy.fit(x, u, args.epochs)
    head = f"{args.bins} levels per action" if args.bins else "tanh"
    report(f"fitted {args.width}x{args.depth} ({head}), {args.epochs} epochs", t0)
    rng = np.random.default_rng(0)
    for k in range(args.rounds):
        starts = task_states(prog.system, task, args.per_round, seed=ROUND_SEED + k)
        r = Evaluator(prog, args.task, starts).run(policy, record=True)
        queries = []
        for i in range(len(starts)):
            end = int(r.t_reach[i]) if np.isfinite(r.t_reach[i]) else int(r.end_step[i])
            path = r.trajectories[i, :max(end, 1)]
            path = path[np.all(np.isfinite(path), axis=1)]
            queries.extend(path[rng.choice(len(path), size=min(args.per_path, len(path)), replace=False)])
        solved = run(prog, args.task, states=np.array(queries), workers=args.workers).results
        xn, un = labels(solved)
        x, u = np.concatenate([x, xn]), np.concatenate([u, un])
        policy.fit(x, u, args.round_epochs)
        report(f"DAgger round {k + 1}: the oracle from {len(queries)} visited states", t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
