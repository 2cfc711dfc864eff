"""Is a trained policy below its own reward's optimum, and does climbing the return directly help?

Two probes over a run of SAC on the sbx engine (docs/training.md, "Below its own reward's optimum"):

- ``headroom``: the oracle on ``--states`` initial states (seed 4242 by default: neither the
  evaluation's nor the validation's); from each, the run's discounted return (its reward, its γ,
  its failure reward) of the policy's own path, and of the oracle's path followed by the policy
  (which holds the goal once there). Where the oracle's path arrives sooner and is worth more, the
  policy is below its own objective's optimum: the learner's error, not the reward's bias.
- ``search``: evolution strategies on the actor's parameters (antithetic Gaussian perturbations of
  ``--sigma``, centred ranks, Adam of ``--lr``), the objective the mean discounted return over
  ``--batch`` fresh initial states per iteration (a new seed each, the same for every
  perturbation), every rollout one batched call of the compiled simulator, no critic. Every
  ``--every`` iterations the deterministic policy is judged on the run's 500 validation states
  (seed 7) and the best kept; the evaluation states (seed 2024) are rolled out only for the policy
  before the search and the one it keeps.

    .venv/bin/python benchmarks/return_search.py headroom RUN [--states 300] [--seed 4242] [--workers 2]
    .venv/bin/python benchmarks/return_search.py search RUN [--iterations 1000] [--population 64]
        [--batch 256] [--sigma 0.01] [--lr 0.003] [--every 25] [--seed 555]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

#: The search's training states: seeds from here on, one per iteration (never 7 or 2024).
SEARCH_SEEDS = 100_000


def discounted_returns(evaluator, controller, states: np.ndarray, gamma: float, failure_reward: float):
    """Per row: the discounted return of the task's reward (a failure step earns ``failure_reward``,
    as in training) and the step ``asap`` first held (inf if never)."""
    core = evaluator.core
    T, m = evaluator.steps, core.system.n_action
    obs = core.start(states, T)
    controller.reset(core.states.copy())
    n = len(states)
    ret, disc = np.zeros(n), 1.0
    running = np.ones(n, dtype=bool)
    t_reach = np.where(core.asap.sat, 0.0, np.inf)
    for t in range(T):
        if not running.any():
            break
        a = np.asarray(controller.act(obs, core.states.copy(), t), dtype=np.float64).reshape(n, m)
        obs, r, failed, _, _, done = core.step(np.clip(a, core.system.action_low, core.system.action_high))
        ret += disc * np.where(failed, failure_reward, r) * running
        newly = running & core.asap.step_sat & ~failed & ~np.isfinite(t_reach)
        t_reach[newly] = t + 1
        disc *= gamma
        running &= ~done
    return ret, t_reach


class Population:
    """The actor's deterministic action for K parameter vectors at once (sbx's SAC actor)."""

    def __init__(self, loaded):
        import jax
        from jax.flatten_util import ravel_pytree

        state = loaded.model.policy.actor_state
        flat, self.unravel = ravel_pytree(state.params)
        self.theta0 = np.asarray(flat, dtype=np.float64)
        apply = state.apply_fn
        self.scaling = loaded.scaling
        self._act = jax.jit(jax.vmap(lambda th, o: apply(self.unravel(th), o).mode()))
        self.thetas = self.theta0[None]

    def reset(self, states: np.ndarray) -> None:
        pass

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        import jax.numpy as jnp

        k = len(self.thetas)
        o = self.scaling.observation(obs).astype(np.float32).reshape(k, len(obs) // k, -1)
        u = np.asarray(self._act(jnp.asarray(self.thetas, dtype=jnp.float32), jnp.asarray(o)))
        return self.scaling.action(u.reshape(len(obs), -1))


def headroom(args, loaded) -> int:
    from asap_dsl.backends.compare.controllers import _Prefix as Prefix  # the look-ahead's: fixed actions, then the base
    from asap_dsl.backends.oracle import run as oracle
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
    ev = Evaluator(prog, cfg.task, states)
    policy = loaded.controller()
    g_pol, t_pol = discounted_returns(ev, policy, states, gamma, fail)
    g_or, t_or = discounted_returns(ev, Prefix(policy, prefix), states, gamma, fail)
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
    from asap_dsl.backends.rl.config import VALIDATION_SEED
    from asap_dsl.backends.rl.validation import validation_score
    from asap_dsl.rollout import Evaluator
    from asap_dsl.sampling import EVAL_SEED, task_states

    prog, cfg = loaded.program, loaded.config
    model = prog.task(cfg.task).model
    gamma, fail = float(cfg.hyper["gamma"]), float(cfg.failure_reward)
    tolerances = [int(k) for k in model.tolerances]
    pop = Population(loaded)
    K, B = args.population, args.batch
    rng = np.random.default_rng(args.seed)
    some = task_states(prog.system, model, 1, seed=SEARCH_SEEDS)
    train_ev = Evaluator(prog, cfg.task, np.repeat(some, K * B, axis=0))
    val_states = task_states(prog.system, model, 500, seed=VALIDATION_SEED)
    val_ev = Evaluator(prog, cfg.task, val_states)
    eval_states = task_states(prog.system, model, 1000, seed=EVAL_SEED)
    eval_ev = Evaluator(prog, cfg.task, eval_states)

    def judge(ev, theta):
        pop.thetas = theta[None]
        g, t_reach = discounted_returns(ev, pop, ev.states, gamma, fail)
        rates = {k: float(np.mean(t_reach <= k)) for k in tolerances}
        return rates, float(g.mean())

    def show(rates):
        return " / ".join(f"{100 * rates[k]:.1f}%" for k in tolerances)

    theta = pop.theta0.copy()
    m1, m2 = np.zeros_like(theta), np.zeros_like(theta)
    best_score, best_theta, best_it = -1.0, theta.copy(), 0
    t0 = time.time()
    for it in range(args.iterations + 1):
        if it % args.every == 0 or it == args.iterations:
            rates, g = judge(val_ev, theta)
            score = validation_score(rates)
            if score > best_score:
                best_score, best_theta, best_it = score, theta.copy(), it
            print(json.dumps({"iteration": it, "validation": rates, "return": round(g, 3),
                              "seconds": round(time.time() - t0, 1)}), flush=True)
        if it == args.iterations:
            break
        x0 = task_states(prog.system, model, B, seed=SEARCH_SEEDS + args.seed * 10_000 + it)
        eps = rng.standard_normal((K // 2, len(theta)))
        eps = np.concatenate([eps, -eps])
        pop.thetas = theta[None] + args.sigma * eps
        g, _ = discounted_returns(train_ev, pop, np.tile(x0, (K, 1)), gamma, fail)
        f = g.reshape(K, B).mean(axis=1)
        ranks = np.empty(K)
        ranks[np.argsort(f)] = np.arange(K)
        grad = ((ranks / (K - 1) - 0.5) @ eps) / (K * args.sigma)
        m1 = 0.9 * m1 + 0.1 * grad
        m2 = 0.999 * m2 + 0.001 * grad ** 2
        theta = theta + args.lr * (m1 / (1 - 0.9 ** (it + 1))) / (np.sqrt(m2 / (1 - 0.999 ** (it + 1))) + 1e-8)
    before, g0 = judge(eval_ev, pop.theta0)
    after, g1 = judge(eval_ev, best_theta)
    print(f"{args.run}: {args.iterations} iterations in {time.time() - t0:.0f} s; kept iteration {best_it} "
          f"(validation score {best_score:.4f})")
    print(f"  evaluation states (seed {EVAL_SEED}), within {' / '.join(map(str, tolerances))}: the policy {show(before)} "
          f"(return {g0:.2f}), after the search {show(after)} (return {g1:.2f})")
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
        bad = "" if (args.iterations >= 1 and args.population >= 2 and args.population % 2 == 0 and args.batch >= 1
                     and args.every >= 1 and args.seed >= 0 and positive) else (
            "--iterations, --batch and --every take positive whole numbers, --population an even one of at least 2, "
            "--sigma and --lr positive finite numbers, --seed a whole number of at least 0")
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
    if loaded.config.engine != "sbx" or loaded.config.algo != "sac":
        print(f"return_search: {args.run} is {loaded.config.algo} on {loaded.config.engine}; the probes read sbx's "
              "SAC actor", file=sys.stderr)
        return 2
    if loaded.program.system.kind not in ("ode", "map") and args.probe == "headroom":
        print("return_search: headroom needs the oracle, hence known dynamics (ode or map)", file=sys.stderr)
        return 2
    return headroom(args, loaded) if args.probe == "headroom" else search(args, loaded)


if __name__ == "__main__":
    raise SystemExit(main())
