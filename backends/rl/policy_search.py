"""Direct policy search after the learner: evolution strategies on the actor's parameters.

Why (docs/training.md, "Below its own reward's optimum"): where the oracle's path from a state
arrives sooner than the policy SAC leaves, it is worth more under that policy's own reward, on
every such state measured: the steps the policy loses are the learner's error (its critic's nearest
hill), not the reward's bias. The task's own measure can be climbed directly instead: every
candidate policy is judged by the one batched, compiled rollout, no critic in between.

The search (Salimans et al., 2017, "Evolution strategies as a scalable alternative to RL"): from
the best model's actor θ, each iteration draws ``population / 2`` Gaussian directions ε and judges
θ ± σε on the same ``batch`` fresh initial states (a new seed each iteration, never the
validation's nor the evaluation's); the fitnesses become centred ranks (the scale of the objective
does not matter, an outlier does not steer), their ε-weighted sum the gradient estimate, and Adam
the step. The objective (:data:`OBJECTIVES`) is the task's: how soon each state reaches its goal
(``arrival``), or the discounted return of the run's reward (``return``). Every ``every``
iterations the deterministic policy is judged on the run's validation states, as the learner's
models are; the model kept is the best, and the search's only if it beats the learner's best.

Before the first iteration the search also chooses the gain its policy acts with
(``action_gains``): the actor's action multiplied before the clip onto the bounds, so that actions
near a bound saturate there (:class:`~.sb3.Scaling`). SAC's squashed Gaussian reaches its bounds
only at infinity, and a minimum-time path rides them; each gain is judged with the unperturbed actor
on the same fresh states, the best kept (the smallest of equals), and the iterations act with it.
With ``gain_for_kept`` the gain is chosen again for the parameters kept at the end
(:meth:`PolicySearch.finish`).

Each iteration is a pure function of :class:`SearchState` (parameters, Adam's moments, the random
generator's state): a checkpoint holds it and a resumed run continues exactly.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any, Callable, Mapping, Optional

import numpy as np

__all__ = ["OBJECTIVES", "SCALES", "SEARCH_SEEDS", "SEARCHABLE", "ActorFamily", "PolicySearch", "SearchSettings",
           "SearchState", "centred_ranks", "crossing_time", "rollout_batch", "smoothing_scale"]

#: The search's training states: seed ``SEARCH_SEEDS + 10,000 x run seed + iteration`` (never the
#: validation's 7 nor the evaluation's 2024).
SEARCH_SEEDS = 100_000

#: (algorithm, engine) whose actor the search perturbs: deterministic given its parameters (SAC's
#: mean action, TD3's and DDPG's action), on JAX, so that a population acts in one vectorised call.
SEARCHABLE = (("sac", "sbx"), ("td3", "sbx"), ("ddpg", "sbx"))

#: What each candidate's states are worth (higher is better):
#: ``arrival``: minus the mean step at which the goal first holds, counting a state that never
#: reaches it within the episode (or fails) as one step past the episode's end;
#: ``return``: the mean discounted return of the run's reward (a failure step earning the run's
#: failure reward, as in training);
#: ``tolerances``: what validation ranks, the mean over the task's tolerances of the share that
#: arrives within each, made smooth: each state counts ``sigmoid((T - a) / TOLERANCE_SOFTNESS)``
#: within tolerance T, ``a`` its arrival interpolated within the step from the goal's robustness
#: (:func:`crossing_time`), so that a candidate arriving sooner within the same step counts.
OBJECTIVES = ("arrival", "return", "tolerances")

#: The ``tolerances`` objective's softness, in steps: half a step, so that a step sooner across a
#: tolerance adds about 0.4 to a state's worth there, and one a few steps from it adds little.
TOLERANCE_SOFTNESS = 0.5

#: The fresh states on which each candidate gain is judged: this many batches of
#: ``population x batch / len(action_gains)`` states each.
GAIN_BATCHES = 4

#: The perturbation scales the search may take (:func:`smoothing_scale`): ``sigma`` times each.
SCALES = (1.0, 10 ** -0.5, 0.1, 10 ** -1.5)


@dataclass(frozen=True)
class SearchSettings:
    """The search's settings (the preset's ``policy_search``; stored in the run's configuration)."""

    iterations: int = 1000
    population: int = 64      # candidates per iteration, in antithetic pairs
    batch: int = 256          # fresh initial states per iteration, the same for every candidate
    sigma: float = 0.01       # the perturbations' standard deviation, in parameter units
    learning_rate: float = 0.003  # Adam's
    every: int = 25           # iterations between validations
    objective: str = "arrival"
    # The perturbations adapt to how sharp the actor is (None: ``sigma`` as given): the largest of
    # ``sigma`` times :data:`SCALES` whose candidates lose at most this much of the validation
    # score (the mean rate over the tolerances) on average against the unperturbed actor, measured
    # once at the start on fresh states; the learning rate follows the same factor. Why
    # (docs/training.md, "The search's step, scaled to the actor"): evolution strategies climb the
    # Gaussian-smoothed objective, and where a perturbation of sigma already ruins the policy, its
    # optimum is another policy's.
    max_smoothing_loss: Optional[float] = None
    # In a time-limited run the learner stops at ``1 - time_share`` of the limit and the search
    # takes the rest; with ``seconds`` it also ends after that many (None: its iterations alone
    # bound it, the same on every machine).
    time_share: float = 0.25
    seconds: Optional[float] = None
    # The gains the policy's action may act with (:class:`~.sb3.Scaling`; None: 1 alone), each
    # at least 1, as many as divide the population; chosen at the start on fresh states for the
    # iterations and, with ``gain_for_kept``, again for the parameters kept at the end.
    action_gains: Optional[tuple] = None
    gain_for_kept: bool = False

    def __post_init__(self) -> None:
        whole = all(isinstance(v, int) and not isinstance(v, bool) and v >= 1
                    for v in (self.iterations, self.batch, self.every, self.population))
        if not whole or self.population % 2:
            raise ValueError("the policy search's iterations, batch and every take whole numbers of at least 1, its "
                             "population an even one")
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0
                   for v in (self.sigma, self.learning_rate)):
            raise ValueError("the policy search's sigma and learning_rate take positive finite numbers")
        if not (isinstance(self.time_share, (int, float)) and 0.0 < self.time_share < 1.0):
            raise ValueError("the policy search's time_share is a share between 0 and 1")
        seconds = self.seconds
        if seconds is not None and not (isinstance(seconds, (int, float)) and not isinstance(seconds, bool)
                                        and 0.0 < seconds < math.inf):
            raise ValueError("the policy search's seconds take a positive finite number or none")
        loss = self.max_smoothing_loss
        if loss is not None and not (isinstance(loss, (int, float)) and not isinstance(loss, bool)
                                     and 0.0 <= loss < math.inf):
            raise ValueError("the policy search's max_smoothing_loss takes a finite number of at least 0, or none")
        gains = self.action_gains
        if gains is not None:
            ok = (isinstance(gains, (list, tuple)) and len(gains) >= 1 and self.population % len(gains) == 0
                  and all(isinstance(g, (int, float)) and not isinstance(g, bool) and math.isfinite(g) and g >= 1.0
                          for g in gains))
            if not ok:
                raise ValueError("the policy search's action_gains take numbers of at least 1, as many as divide "
                                 "its population, or none")
            object.__setattr__(self, "action_gains", tuple(sorted(float(g) for g in gains)))
        if not isinstance(self.gain_for_kept, bool):
            raise ValueError("the policy search's gain_for_kept is true or false")
        if self.objective not in OBJECTIVES:
            raise ValueError(f"the policy search's objective is one of {', '.join(OBJECTIVES)}; got {self.objective!r}")

    def to_dict(self) -> dict:
        d = asdict(self)
        if d["action_gains"] is not None:
            d["action_gains"] = list(d["action_gains"])  # as JSON gives it back
        return d

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "SearchSettings":
        names = {f.name for f in fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise ValueError(f"the policy search has no setting {', '.join(sorted(unknown))}")
        return cls(**dict(data))


@dataclass
class SearchState:
    """Everything the next iteration depends on; a checkpoint stores it whole."""

    iteration: int
    theta: np.ndarray
    first: np.ndarray          # Adam's first moment
    second: np.ndarray         # ... and second
    rng: dict                  # the directions' generator's state
    best_theta: np.ndarray
    best_score: float          # the validation score to beat: the learner's best, then the search's
    best_iteration: Optional[int] = None  # None: no search iterate has beaten the learner's best yet
    seconds: float = 0.0
    validations: list = field(default_factory=list)  # {"iteration", "score", "rates"} per validation
    scale: float = 1.0         # the factor on sigma and the learning rate (:func:`smoothing_scale`)
    gain: float = 1.0          # the action gain the candidates act with (:meth:`PolicySearch.choose_gain`)
    kept_gain: Optional[float] = None  # the gain chosen again for the kept parameters (None: not chosen again)
    kept_row: Optional[dict] = None    # their validation with it

    def summary(self, score_before: float) -> dict:
        """What the run's manifest records of the search (``policy_search``)."""
        return {"iterations": self.iteration, "seconds": round(self.seconds, 3), "kept_iteration": self.best_iteration,
                "score_before": float(score_before), "score": self.kept_score, "scale": self.scale,
                "action_gain": self.deployed_gain, "search_gain": self.gain, "validations": self.validations}

    @property
    def kept_score(self) -> float:
        """The validation score of the model kept (with the gain chosen again for it, if taken)."""
        return self.kept_row["score"] if self.kept_row is not None else round(self.best_score, 6)

    @property
    def deployed_gain(self) -> float:
        """The gain the kept parameters act with: chosen again for them, else the iterations'."""
        return self.gain if self.kept_gain is None else self.kept_gain

    def kept(self) -> Optional[dict]:
        """The validation row of the model kept (None: the learner's model stays): the iteration's,
        or its validation with the gain chosen again for it."""
        if self.kept_row is not None:
            return self.kept_row
        return next((r for r in self.validations if r["iteration"] == self.best_iteration), None)


def crossing_time(step: np.ndarray, before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """When the goal's robustness crossed zero within each arrival ``step``: linearly between its
    value before the step (negative) and after it (at least 0), ``step`` itself where either is
    not finite or the goal held already."""
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where((before < 0) & (after >= 0) & np.isfinite(before) & np.isfinite(after),
                         after / (after - before), 0.0)
    return step - np.clip(share, 0.0, 1.0)


def rollout_batch(evaluator, controller, states: np.ndarray, gamma: float, failure_reward: Optional[float]):
    """Per row of ``states``: the discounted return of the evaluator's reward (a failure step
    earning ``failure_reward``, as in training; None: the reward's own), the step at which the
    goal first holds (inf if never, or after a failure) and that arrival within its step
    (:func:`crossing_time`)."""
    core = evaluator.core
    T, m = evaluator.steps, core.system.n_action
    obs = core.start(states, T)
    controller.reset(core.states.copy())
    n = len(states)
    ret, disc = np.zeros(n), 1.0
    running = np.ones(n, dtype=bool)
    arrival = np.where(core.asap.sat, 0.0, np.inf)
    crossing = arrival.copy()
    before = np.array(core.asap.rob, dtype=np.float64)
    for t in range(T):
        if not running.any():
            break
        a = np.asarray(controller.act(obs, core.states.copy(), t), dtype=np.float64).reshape(n, m)
        obs, r, failed, _, _, done = core.step(np.clip(a, core.system.action_low, core.system.action_high))
        if failure_reward is not None:
            r = np.where(failed, failure_reward, r)
        ret += disc * r * running
        after = np.array(core.asap.step_rob, dtype=np.float64)
        newly = running & core.asap.step_sat & ~failed & ~np.isfinite(arrival)
        arrival[newly] = t + 1
        crossing[newly] = crossing_time(t + 1.0, before[newly], after[newly])
        before = after
        disc *= gamma
        running &= ~done
    return ret, arrival, crossing


def smoothing_scale(loss_at: Callable[[float], float], max_loss: float) -> float:
    """The largest of :data:`SCALES` at which ``loss_at(scale)`` (the candidates' mean loss of
    validation score against the unperturbed actor) is at most ``max_loss``; the smallest if none."""
    for scale in SCALES:
        if loss_at(scale) <= max_loss:
            return scale
    return SCALES[-1]


def centred_ranks(f: np.ndarray) -> np.ndarray:
    """Ranks of ``f`` mapped onto [-0.5, 0.5], tied values sharing their mean rank (candidates
    that did equally well pull no way: on a batch where none reaches, the step is nothing)."""
    ranks = np.empty(len(f))
    ranks[np.argsort(f, kind="stable")] = np.arange(len(f))
    _, tie, counts = np.unique(f, return_inverse=True, return_counts=True)
    ranks = (np.bincount(tie, ranks) / counts)[tie]
    return ranks / max(1, len(f) - 1) - 0.5


class ActorFamily:
    """The actor's deterministic action for K parameter vectors at once (a controller for the
    rollout: rows come in K equal blocks, block k acting with ``thetas[k]``)."""

    def __init__(self, model, algo: str, scaling):
        import jax
        from jax.flatten_util import ravel_pytree

        state = model.policy.actor_state
        flat, self._unravel = ravel_pytree(state.params)
        self.theta0 = np.asarray(flat, dtype=np.float64)
        apply = state.apply_fn
        mode = algo == "sac"  # SAC's actor gives a distribution: its mean action (tanh of the mean)
        self._act = jax.jit(jax.vmap(lambda th, o: apply(self._unravel(th), o).mode() if mode
                                     else apply(self._unravel(th), o)))
        self.scaling = scaling
        self.thetas = self.theta0[None]

    @property
    def gain(self):
        """The action gain the rows act with: a float, or per row ``[rows, 1]``
        (:meth:`PolicySearch.choose_gain`); held by the scaling, set once per rollout, not per step."""
        return self.scaling.gain

    @gain.setter
    def gain(self, value) -> None:
        self.scaling = replace(self.scaling, gain=value)

    def reset(self, states: np.ndarray) -> None:
        pass

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        import jax.numpy as jnp

        k = len(self.thetas)
        o = self.scaling.observation(obs).astype(np.float32).reshape(k, len(obs) // k, -1)
        u = np.asarray(self._act(jnp.asarray(self.thetas, dtype=jnp.float32), jnp.asarray(o)))
        return self.scaling.action(u.reshape(len(obs), -1))

    def install(self, model, theta: np.ndarray) -> None:
        """``theta`` becomes ``model``'s actor's parameters."""
        import jax.numpy as jnp

        state = model.policy.actor_state
        params = self._unravel(jnp.asarray(theta, dtype=jnp.float32))
        model.policy.actor_state = state.replace(params=params)


class PolicySearch:
    """The search over one run's actor: :meth:`iterate` one step, :meth:`validate` the current
    parameters; the caller decides when (the session: every ``settings.every`` iterations, and
    stops, time limits and checkpoints). ``validator``: the run's validation evaluator; ``score``:
    its rates' ranking (:func:`.validation.validation_score`)."""

    def __init__(self, prog, task: str, settings: SearchSettings, family: ActorFamily, validator, score,
                 *, reward: Any, gamma: float, failure_reward: Optional[float], seed: int):
        from asap_dsl.rollout import Evaluator
        from asap_dsl.sampling import task_states

        self.prog, self.settings, self.family, self.validator, self.score = prog, settings, family, validator, score
        self.model = prog.task(task).model
        self.gamma, self.failure_reward, self.seed = float(gamma), failure_reward, int(seed)
        self.tolerances = sorted(int(k) for k in self.model.tolerances)
        K, B = settings.population, settings.batch
        some = task_states(prog.system, self.model, 1, seed=SEARCH_SEEDS)
        self.trainer = Evaluator(prog, task, np.repeat(some, K * B, axis=0), reward=reward)

    def _tolerances(self) -> list[int]:
        """The tolerances the rates are counted within (a task without any: its episode's length)."""
        return self.tolerances or [int(self.trainer.steps)]

    def start(self, best_score: float) -> SearchState:
        """A search from the family's parameters, to beat ``best_score`` on validation; its
        perturbations' scale chosen for this actor (:attr:`SearchSettings.max_smoothing_loss`)."""
        theta = self.family.theta0.copy()
        rng = np.random.default_rng([SEARCH_SEEDS, self.seed])
        gain = self.choose_gain(theta)
        self.family.gain = gain
        scale = 1.0
        if self.settings.max_smoothing_loss is not None:
            scale = smoothing_scale(lambda f: self.smoothing_loss(theta, self.settings.sigma * f),
                                    float(self.settings.max_smoothing_loss))
        return SearchState(iteration=0, theta=theta, first=np.zeros_like(theta), second=np.zeros_like(theta),
                           rng=rng.bit_generator.state, best_theta=theta.copy(), best_score=float(best_score),
                           scale=float(scale), gain=gain)

    def choose_gain(self, theta: np.ndarray) -> float:
        """The action gain of :attr:`SearchSettings.action_gains` under which ``theta`` scores best
        (the validation's ranking of its rates) on :data:`GAIN_BATCHES` batches of fresh states,
        every gain on the same states; the smallest of equals, 1 without candidates."""
        from asap_dsl.sampling import task_states

        gains = self.settings.action_gains or (1.0,)
        if self.family.scaling.act_low is None:  # actions not scaled onto [-1, 1]: no gain to take
            return 1.0
        if len(gains) == 1:
            return float(gains[0])
        K, B, G = self.settings.population, self.settings.batch, len(gains)
        per = K * B // G
        self.family.thetas = np.repeat(theta[None], G, axis=0)
        self.family.gain = np.repeat(np.asarray(gains, dtype=np.float64), per)[:, None]
        within = sum(self._block_rates(task_states(self.prog.system, self.model, per,
                                                   seed=SEARCH_SEEDS - 1_000 - 10 * self.seed - b), G)
                     for b in range(GAIN_BATCHES))
        score = self._block_scores(within / GAIN_BATCHES)
        self.family.gain = 1.0
        return float(gains[int(np.argmax(score))])  # argmax: the first, the smallest gain, among equals

    def smoothing_loss(self, theta: np.ndarray, sigma: float) -> float:
        """How much of the validation score (the mean rate over the tolerances) candidates
        perturbed by ``sigma`` lose on average against ``theta`` itself: half a population of
        blocks (the first unperturbed), each on the same fresh states (never the validation's)."""
        from asap_dsl.sampling import task_states

        K, B = self.settings.population, self.settings.batch
        blocks = K // 2
        x0 = task_states(self.prog.system, self.model, K * B // blocks, seed=SEARCH_SEEDS - 1 - self.seed)
        eps = np.random.default_rng([SEARCH_SEEDS - 1, self.seed]).standard_normal((blocks, len(theta)))
        eps[0] = 0.0
        self.family.thetas = theta[None] + sigma * eps
        score = self._block_scores(self._block_rates(x0, blocks))
        return float(score[0] - score[1:].mean())

    def _block_rates(self, x0: np.ndarray, blocks: int) -> np.ndarray:
        """``[blocks, tolerances]``: the rate within each tolerance of each block of the family's
        rows, every block started on the states ``x0``."""
        _, arrival, _ = rollout_batch(self.trainer, self.family, np.tile(x0, (blocks, 1)), self.gamma,
                                      self.failure_reward)
        return np.stack([(arrival <= T).reshape(blocks, -1).mean(axis=1) for T in self._tolerances()], axis=1)

    def _block_scores(self, rates: np.ndarray) -> np.ndarray:
        """Each row of :meth:`_block_rates` ranked as validation ranks its rates."""
        return np.array([self.score(dict(zip(self._tolerances(), row))) for row in rates])

    def fitness(self, returns: np.ndarray, arrival: np.ndarray, crossing: np.ndarray) -> np.ndarray:
        """Each candidate's worth (higher is better) from its rows' returns, arrival steps and
        arrivals within the step."""
        K = self.settings.population
        if self.settings.objective == "return":
            return returns.reshape(K, -1).mean(axis=1)
        if self.settings.objective == "tolerances":
            T = np.asarray(self._tolerances(), dtype=np.float64)
            a = np.where(np.isfinite(crossing), crossing, np.inf)[:, None]
            within = 1.0 / (1.0 + np.exp(np.clip((a - T[None]) / TOLERANCE_SOFTNESS, -50.0, 50.0)))
            return within.mean(axis=1).reshape(K, -1).mean(axis=1)
        late = float(self.trainer.steps + 1)  # never reached: one step past the episode
        return -np.minimum(arrival, late).reshape(K, -1).mean(axis=1)

    def iterate(self, state: SearchState) -> SearchState:
        """One iteration: the population judged on fresh states, one Adam step. Pure in ``state``."""
        from asap_dsl.sampling import task_states

        s = self.settings
        K, it = s.population, state.iteration
        rng = np.random.default_rng()
        rng.bit_generator.state = state.rng
        eps = rng.standard_normal((K // 2, len(state.theta)))
        eps = np.concatenate([eps, -eps])
        x0 = task_states(self.prog.system, self.model, s.batch, seed=SEARCH_SEEDS + 10_000 * self.seed + it)
        sigma = s.sigma * state.scale
        self.family.thetas = state.theta[None] + sigma * eps
        self.family.gain = state.gain
        returns, arrival, crossing = rollout_batch(self.trainer, self.family, np.tile(x0, (K, 1)), self.gamma,
                                                   self.failure_reward)
        f = self.fitness(returns, arrival, crossing)
        grad = (centred_ranks(f) @ eps) / (K * sigma)
        first = 0.9 * state.first + 0.1 * grad
        second = 0.999 * state.second + 0.001 * grad ** 2
        step = (first / (1 - 0.9 ** (it + 1))) / (np.sqrt(second / (1 - 0.999 ** (it + 1))) + 1e-8)
        return SearchState(iteration=it + 1, theta=state.theta + s.learning_rate * state.scale * step, first=first,
                           second=second, rng=rng.bit_generator.state, best_theta=state.best_theta,
                           best_score=state.best_score, best_iteration=state.best_iteration, seconds=state.seconds,
                           validations=list(state.validations), scale=state.scale, gain=state.gain)

    def validate(self, state: SearchState) -> dict:
        """The current parameters on the validation states; the best kept in ``state`` if they
        beat it (strictly: a tie keeps what came first, the learner's model). Returns the row."""
        row = {"iteration": state.iteration, **self._judge(state.theta, state.gain)}
        score = float(self.score(row["rates"]))  # unrounded, as the learner's best was
        if score > state.best_score:
            state.best_theta, state.best_score, state.best_iteration = state.theta.copy(), score, state.iteration
            row["best"] = 1
        state.validations.append(row)
        return row

    def run(self, state: SearchState, stopped: Callable[[], bool], after: Callable[[SearchState], None]) -> SearchState:
        """Iterate from ``state`` to the settings' iterations (or their seconds), validating every
        ``every``; ``stopped()`` ends it early (a signal, a time limit) and ``after(state)`` follows
        each iteration (the caller checkpoints when one is due). :meth:`finish` validates the last."""
        s = self.settings
        started, before = time.perf_counter(), state.seconds
        while state.iteration < s.iterations and not stopped():
            if s.seconds is not None and before + time.perf_counter() - started >= s.seconds:
                break
            state = self.iterate(state)
            if state.iteration % s.every == 0:
                self.validate(state)
            state.seconds = before + time.perf_counter() - started
            after(state)
        return state

    def finish(self, state: SearchState, to_beat: float) -> SearchState:
        """The last parameters validated, as the learner's are at its end; with ``gain_for_kept``,
        the gain chosen again for the parameters kept (the search moved the actor the first choice
        was made for), taken if their validation with it still beats ``to_beat`` (the learner's)."""
        if not state.validations or state.validations[-1]["iteration"] != state.iteration:
            self.validate(state)
        if not self.settings.gain_for_kept or state.best_iteration is None or state.kept_gain is not None:
            return state
        gain = self.choose_gain(state.best_theta)
        state.kept_gain = state.gain
        if gain != state.gain:
            row = self._judge(state.best_theta, gain)
            if float(self.score(row["rates"])) > to_beat:
                state.kept_gain, state.kept_row = gain, {**row, "iteration": state.best_iteration, "gain": gain}
        return state

    def _judge(self, theta: np.ndarray, gain: float) -> dict:
        """``theta`` acting with ``gain`` on the validation states: a validation row."""
        t0 = time.perf_counter()
        self.family.thetas, self.family.gain = theta[None], gain
        res = self.validator.run(self.family)
        rates = {T: res.rate(T) for T in self.tolerances}
        return {"score": round(float(self.score(rates)), 6), "rates": rates,
                "return": round(float(np.mean(res.returns)), 6), "seconds": round(time.perf_counter() - t0, 3)}
