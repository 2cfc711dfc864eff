"""Is a trained policy below its own reward's optimum, and does climbing the return directly help?

Two probes over a run of SAC on the sbx engine (docs/training.md, "Below its own reward's optimum"):

- ``headroom``: the oracle on ``--states`` initial states (seed 4242 by default: neither the
  evaluation's nor the validation's); from each, the run's discounted return (its reward, its γ,
  its failure reward) of the policy's own path, and of the oracle's path followed by the policy
  (which holds the goal once there). Where the oracle's path arrives sooner and is worth more, the
  policy is below its own objective's optimum: the learner's error, not the reward's bias.
- ``search``: the policy search of the default preset (:mod:`asap_dsl.backends.rl.policy_search`:
  evolution strategies on the actor, the objective ``--objective``) on a finished run's model, in
  place of the run's own (the run is not changed): the deterministic policy is judged on the run's
  validation states every ``--every`` iterations and the best kept; the evaluation states (seed
  2024) are rolled out only for the policy before the search and the one it keeps.

    .venv/bin/python benchmarks/return_search.py headroom RUN [--states 300] [--seed 4242] [--workers 2]
    .venv/bin/python benchmarks/return_search.py search RUN [--iterations 1000] [--population 64]
        [--batch 256] [--sigma 0.01] [--lr 0.003] [--every 25] [--seed 555] [--objective arrival] [--validation N]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

def headroom(args, loaded) -> int:
    from asap_dsl.backends.compare.controllers import _Prefix as Prefix  # the look-ahead's: fixed actions, then the base
    from asap_dsl.backends.oracle import run as oracle
    from asap_dsl.backends.rl.policy_search import rollout_batch
    from asap_dsl.rollout import Evaluator
    from asap_dsl.sampling import task_states

    prog, cfg = loaded.program, loaded.config
    model = prog.task(cfg.task).model
    gamma, fail = float(cfg.hyper["gamma"]), float(cfg.failure_reward)
    states = task_states(prog.system, model, args.states, seed=args.seed)
    t0 = time.time()
    results = oracle(prog, cfg.task, states=states, workers=args.workers).results
    m = prog.system.n_action
    prefix = np.full((int(model.deadline), len(states), m), np.nan)
    for i, r in enumerate(results):
        if r.actions is not None and len(r.actions):
            a = np.asarray(r.actions).reshape(-1, m)
            prefix[:len(a), i] = a
    ev = Evaluator(prog, cfg.task, states, reward=cfg.reward)
    policy = loaded.controller()
    g_pol, t_pol, _ = rollout_batch(ev, policy, states, gamma, fail)
    g_or, t_or, _ = rollout_batch(ev, Prefix(policy, prefix), states, gamma, fail)
    sooner = np.isfinite(t_or) & (t_or < t_pol)
    same = np.isfinite(t_or) & (t_or == t_pol)
    print(f"{args.run}: the oracle on {len(states)} states (seed {args.seed}) in {time.time() - t0:.0f} s")
    print(f"  the oracle's path (then the policy) arrives sooner on {sooner.sum()} states, at the same step on {same.sum()}")
    if sooner.any():
        print(f"  where sooner: mean discounted return, the policy's path {g_pol[sooner].mean():.2f}, the oracle's "
              f"{g_or[sooner].mean():.2f}; the oracle's worth more on {100 * (g_or[sooner] > g_pol[sooner]).mean():.1f}%")
    print(f"  all states: mean discounted return, the policy {g_pol.mean():.2f}, the oracle's paths then the policy "
          f"{g_or.mean():.2f}")
    return 0


def search(args, loaded) -> int:
    from asap_dsl.backends.rl.policy_search import ActorFamily, PolicySearch, SearchSettings
    from asap_dsl.backends.rl.validation import validation_score
    from asap_dsl.rollout import Evaluator
    from asap_dsl.sampling import EVAL_SEED, task_states

    prog, cfg = loaded.program, loaded.config
    model = prog.task(cfg.task).model
    tolerances = sorted(int(k) for k in model.tolerances)
    settings = SearchSettings(iterations=args.iterations, population=args.population, batch=args.batch,
                              sigma=args.sigma, learning_rate=args.lr, every=args.every, objective=args.objective)
    family = ActorFamily(loaded.model, cfg.algo, loaded.scaling)
    val_states = task_states(prog.system, model, args.validation or cfg.validation_episodes, seed=cfg.validation_seed)
    validator = Evaluator(prog, cfg.task, val_states, reward=cfg.reward)
    search = PolicySearch(prog, cfg.task, settings, family, validator, validation_score, reward=cfg.reward,
                          gamma=float(cfg.hyper["gamma"]), failure_reward=cfg.failure_reward, seed=args.seed)
    state = search.start(-1.0)  # the policy itself is the first validation's
    t0 = time.time()

    shown: set = set()

    def show(state) -> None:
        row = state.validations[-1]
        if row["iteration"] == state.iteration and row["iteration"] not in shown:
            shown.add(row["iteration"])
            print(json.dumps({"iteration": state.iteration, "validation": row["rates"], "return": row["return"],
                              "seconds": round(time.time() - t0, 1)}), flush=True)

    search.validate(state)
    show(state)
    state = search.finish(search.run(state, lambda: False, show), state.best_score)
    show(state)
    evaluator = Evaluator(prog, cfg.task, task_states(prog.system, model, 1000, seed=EVAL_SEED), reward=cfg.reward)

    def judge(theta):
        family.thetas = theta[None]
        res = evaluator.run(family)
        return " / ".join(f"{100 * res.rate(T):.1f}%" for T in tolerances), float(np.mean(res.returns))

    (before, g0), (after, g1) = judge(family.theta0), judge(state.best_theta)
    print(f"{args.run}: {args.iterations} iterations in {time.time() - t0:.0f} s; kept iteration {state.best_iteration} "
          f"(validation score {state.best_score:.4f})")
    print(f"  evaluation states (seed {EVAL_SEED}), within {' / '.join(map(str, tolerances))}: the policy {before} "
          f"(return {g0:.2f}), after the search {after} (return {g1:.2f})")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="probe", required=True)
    h = sub.add_parser("headroom")
    h.add_argument("run")
    h.add_argument("--states", type=int, default=300)
    h.add_argument("--seed", type=int, default=4242)
    h.add_argument("--workers", type=int, default=2)
    s = sub.add_parser("search")
    s.add_argument("run")
    s.add_argument("--iterations", type=int, default=1000)
    s.add_argument("--population", type=int, default=64)
    s.add_argument("--batch", type=int, default=256)
    s.add_argument("--sigma", type=float, default=0.01)
    s.add_argument("--lr", type=float, default=0.003)
    s.add_argument("--every", type=int, default=25)
    s.add_argument("--seed", type=int, default=555)
    s.add_argument("--objective", choices=("arrival", "return", "tolerances"), default="arrival")
    s.add_argument("--validation", type=int, default=0, help="validation states (default: the run's)")
    args = ap.parse_args()
    from asap_dsl.backends.rl.config import VALIDATION_SEED
    from asap_dsl.backends.rl.evaluation import load_run
    from asap_dsl.limits import ResourceLimit, check_batch
    from asap_dsl.runs import RunError
    from asap_dsl.sampling import EVAL_SEED

    if args.probe == "headroom":
        bad = "" if args.states >= 1 and args.workers >= 1 and args.seed >= 0 and args.seed not in (
            EVAL_SEED, VALIDATION_SEED) else (
            "--states and --workers take positive whole numbers, --seed a whole number of at least 0 that is neither "
            f"the evaluation's ({EVAL_SEED}) nor the validation's ({VALIDATION_SEED})")
    else:
        positive = all(math.isfinite(x) and x > 0 for x in (args.sigma, args.lr))
        whole = min(args.iterations, args.batch, args.every) >= 1 and args.validation >= 0 and args.seed >= 0
        bad = "" if whole and args.population >= 2 and args.population % 2 == 0 and positive else (
            "--iterations, --batch and --every take positive whole numbers, --validation 0 or more, --population an "
            "even one of at least 2, --sigma and --lr positive finite numbers, --seed a whole number of at least 0")
    if bad:
        print(f"return_search: {bad}", file=sys.stderr)
        return 2
    try:
        loaded = load_run(args.run)
    except RunError as err:
        print(f"return_search: {err}", file=sys.stderr)
        return 1
    if args.probe == "search":
        try:  # the population's rollouts: one batched environment of population x batch rows
            check_batch(loaded.program, loaded.config.task, args.population * args.batch,
                        f"--population {args.population} x --batch {args.batch}", loaded.config.reward)
        except ResourceLimit as err:
            print(f"return_search: {err}", file=sys.stderr)
            return 2
    from asap_dsl.backends.rl.policy_search import SEARCHABLE

    if (loaded.config.algo, loaded.config.engine) not in SEARCHABLE:
        print(f"return_search: {args.run} is {loaded.config.algo} on {loaded.config.engine}; the probes read the actor "
              "of SAC, TD3 or DDPG on sbx", file=sys.stderr)
        return 2
    if loaded.program.system.kind not in ("ode", "map") and args.probe == "headroom":
        print("return_search: headroom needs the oracle, hence known dynamics (ode or map)", file=sys.stderr)
        return 2
    return headroom(args, loaded) if args.probe == "headroom" else search(args, loaded)


if __name__ == "__main__":
    raise SystemExit(main())
