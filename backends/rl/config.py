"""The resolved configuration of a training run: preset, then the task's ``train { ... }`` block,
then explicit arguments (strongest). Pure: reads a checked program, writes nothing.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Mapping, Optional

from asap_dsl.checker_common import ALGORITHMS, OBSERVATION_SCALINGS, RUN_SETTINGS, setting_problem
from asap_dsl.observation import observation_sources
from asap_dsl.rewards import check_reward_fits, resolve_reward
from asap_dsl.sampling import EVAL_SEED

from .presets import OFF_POLICY, discount, get_preset
from .engines import ENGINES, REFERENCE, choose_engine
from .policy_search import SEARCHABLE, SearchSettings
from .validation import validation_states
from . import hyper as _hyper

__all__ = ["ConfigError", "TrainConfig", "VALIDATION_SEED", "resolve_config"]

#: Seed of the validation states that pick the best model during training. It is not the
#: evaluation seed: choosing a model on the states it is then judged on would flatter it.
VALIDATION_SEED = 7
assert VALIDATION_SEED != EVAL_SEED

# Settings of a ``train { ... }`` block that are hyperparameters of the algorithm (the rest —
# algo, steps, seed, preset, n_envs, eval_episodes — are the run's own).
_RUN_KEYS = tuple(RUN_SETTINGS)


class ConfigError(ValueError):
    """A setting that cannot be used; the message is one sentence for the user."""


# What each stored field must be (the annotations, as text), and how a message names it.
_STORED_TYPES = {"str": (str,), "int": (int,), "bool": (bool,), "dict[str, Any]": (dict,), "float": (int, float),
                 "Optional[float]": (int, float, type(None)), "Optional[dict[str, str]]": (dict, type(None)),
                 "Optional[dict[str, Any]]": (dict, type(None))}
_TYPE_WORDS = {"str": "a text", "int": "a whole number", "bool": "true or false", "dict[str, Any]": "an object",
               "float": "a number", "Optional[float]": "a number or null",
               "Optional[dict[str, str]]": "an object or null", "Optional[dict[str, Any]]": "an object or null"}

# Fields added after sweeps were made, with the value that means "off": left out of a run's key
# (:attr:`TrainConfig.key`) while off, so that a finished run is still found by a sweep.
_KEY_WHEN_SET = {"plateau": None, "plateau_after": None, "stall_demonstrations": 0, "imitation": 0.0,
                 "policy_search": None}


@dataclass
class TrainConfig:
    """Everything that decides a training run (stored in the run's manifest)."""

    task: str
    algo: str
    engine: str               # the library that trains it (:mod:`.engines`)
    reward: str
    seed: int
    preset: str
    steps: int
    n_envs: int
    torch_threads: int
    observation_scaling: str
    action_scaling: bool
    time_limit_terminal: bool
    validation_episodes: int
    validation_seed: int
    validate_every: int
    eval_episodes: int
    hyper: dict[str, Any] = field(default_factory=dict)
    time_limit: Optional[float] = None  # seconds of training; the run ends (finished) when they are spent
    demonstrations: int = 0   # initial states whose oracle sequences fill the replay buffer first (:mod:`.demonstrations`)
    late_demonstrations: int = 0  # ... or later, when no validation has succeeded (:mod:`.exploration`)
    stall_demonstrations: int = 0  # ... or when validation has stopped improving (:mod:`.exploration`)
    sparse_gamma: Optional[float] = None  # the discount once the late rule found nothing (None: the run's own)
    # Of the demonstrations' sequences the longest this share is kept, each this many times, the
    # oracle searching for at most these seconds (None: no bound but its time per state).
    demonstration_share: float = 1.0
    demonstration_repeat: int = 1
    demonstration_seconds: Optional[float] = None
    # The actor imitates the demonstrations (all of them, kept as they are) with this weight
    # (:mod:`.imitation`; 0: not), the oracle searching for them at most ``imitation_seconds``.
    imitation: float = 0.0
    imitation_seconds: Optional[float] = None
    # ... or, once the late rule found nothing, with this weight the paths it then searches for
    # (:mod:`.exploration`; 0: its few sequences alone), as many as ``imitation_states`` or the
    # seconds above buy.
    sparse_imitation: float = 0.0
    imitation_states: int = 0
    failed_starts: float = 0.0  # the share of new episodes started where an earlier one failed (:mod:`.curriculum`)
    plateau: Optional[float] = None  # the run ends once this latest share of its steps brought validation nothing
    plateau_after: Optional[float] = None  # ... but not before this share of its steps
    # The learner's reward of a failure step (None: the reward's floor, as the task defines it).
    failure_reward: Optional[float] = None
    # Each state entry's scaling box (init, state or none: asap_dsl.observation); None in runs from
    # before it was recorded, which used observation_scaling's box for every entry.
    observation_sources: Optional[dict[str, str]] = None
    # After the learner, evolution strategies on the best actor with these settings
    # (:class:`.policy_search.SearchSettings`; None: no search).
    policy_search: Optional[dict[str, Any]] = None

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "TrainConfig":
        names = {f.name for f in fields(cls)}
        data = {"engine": REFERENCE, **data}  # a run from before engines: stable-baselines3 trained it
        missing = names - set(data) - {"time_limit", "demonstrations", "late_demonstrations", "observation_sources",
                                         "demonstration_share", "demonstration_repeat", "demonstration_seconds",
                                         "failed_starts", "failure_reward", "sparse_gamma", "imitation_seconds",
                                         "sparse_imitation", "imitation_states",
                                         *_KEY_WHEN_SET}  # runs from before them had none
        if missing:
            raise ConfigError(f"the stored configuration lacks {', '.join(sorted(missing))}")
        for f in fields(cls):  # a manifest edited by hand: one sentence, not a crash deep in training
            want = _STORED_TYPES.get(str(f.type))
            value = data.get(f.name)
            if f.name in data and want is not None and not (isinstance(value, want) and
                                                           (bool in want or not isinstance(value, bool))):
                raise ConfigError(f"the stored configuration has {f.name} = {value!r}, not {_TYPE_WORDS[str(f.type)]}")
        for name, allowed in (("algo", ALGORITHMS), ("engine", ENGINES), ("observation_scaling", OBSERVATION_SCALINGS)):
            if name in data and data[name] not in allowed:
                raise ConfigError(f"the stored configuration has {name} = {data[name]!r}, not one of {', '.join(allowed)}")
        for name in ("steps", "n_envs", "seed", "eval_episodes"):
            problem = setting_problem(name, data.get(name))
            if problem is not None:
                raise ConfigError(f"the stored configuration's {problem}")
        if data.get("policy_search") is not None:
            try:
                SearchSettings.from_dict(data["policy_search"])
            except (TypeError, ValueError) as err:
                raise ConfigError(f"the stored configuration's policy search: {err}") from None
        return cls(**{k: data[k] for k in names if k in data})

    def failure_reward_at(self, gamma: float) -> Optional[float]:
        """The learner's reward of a failure step under the discount ``gamma`` (the late rule
        changes it mid-run): the same floor earned for every step after it, ``floor / (1 - gamma)``
        (:func:`_failure_reward`); None where the run has none."""
        if self.failure_reward is None:
            return None
        floor = float(self.failure_reward) * (1.0 - float(self.hyper.get("gamma", 0.99)))
        return floor / (1.0 - float(gamma))

    @property
    def key(self) -> dict:
        """What makes two runs the same experiment (a sweep reuses a run when these agree)."""
        d = self.to_dict()
        d.pop("validate_every", None)
        d.pop("time_limit", None)
        d.pop("demonstration_seconds", None)  # follows from the time limit
        d.pop("imitation_seconds", None)
        # Acts only once the late rule found nothing (the manifest's late_demonstrations says so):
        # a run where it never fired, every benchmark's, is the same experiment with or without it.
        d.pop("sparse_gamma", None)
        d.pop("sparse_imitation", None)  # the same
        d.pop("imitation_states", None)
        for name, off in _KEY_WHEN_SET.items():  # a rule added since: runs without it keep their key
            if d.get(name) == off:
                d.pop(name, None)
        return d


def resolve_config(prog, task: Optional[str] = None, *, algo: Optional[str] = None, reward: Optional[str] = None,
                   steps: Optional[int] = None, seed: Optional[int] = None, preset: Optional[str] = None,
                   n_envs: Optional[int] = None, settings: Optional[Mapping[str, Any]] = None,
                   eval_episodes: Optional[int] = None, time_limit: Optional[float] = None,
                   engine: Optional[str] = None, demonstrations: Optional[int] = None,
                   failed_starts: Optional[float] = None, imitation: Optional[float] = None,
                   search_iterations: Optional[int] = None) -> TrainConfig:
    """Resolve the configuration of training ``task`` of ``prog``.

    ``settings`` are hyperparameters by their ``train { ... }`` names (they override the block
    and the preset). ``engine``: ``sbx`` or ``sb3`` (default: the preset's where it has the
    algorithm). ``demonstrations``: initial states whose oracle sequences go into the replay
    buffer before learning (default: the preset's where the algorithm has a replay buffer and the
    dynamics are known; 0: none); of their sequences the preset's longest share is kept.
    ``failed_starts``: the share of new training episodes that start at the initial state of an
    earlier one that did not reach (:mod:`.curriculum`; default: the preset's). ``imitation``: the
    weight of the actor's imitation of the oracle's paths (:mod:`.imitation`; default: the
    preset's; SAC on sbx with known dynamics only): their states are ``demonstrations`` or the
    preset's ``imitation_states``, at the start, kept as they are. ``search_iterations``: the
    policy search's iterations after the learner (:mod:`.policy_search`; default: the preset's,
    at most one per ``search_steps`` training steps; 0: none; SAC, TD3 and DDPG on sbx). Raises
    :class:`ConfigError` (one sentence) or ``KeyError`` (unknown task).
    """
    t = prog.task(task).model  # KeyError with a suggestion on an unknown task
    block = dict(t.train)
    preset_name = preset or block.get("preset") or "default"
    try:
        p = get_preset(preset_name)
    except KeyError as err:
        raise ConfigError(err.args[0]) from None
    algo = (algo or block.get("algo") or p.algo).lower()
    if algo not in ALGORITHMS:
        from asap_dsl.diagnostics import closest

        sug = closest(algo, ALGORITHMS)
        raise ConfigError(f"unknown algorithm '{algo}'" + (f"; did you mean '{sug}'?" if sug else f"; choose {', '.join(ALGORITHMS)}"))
    try:
        engine = choose_engine(engine, p.engine, algo)
    except ValueError as err:
        raise ConfigError(str(err)) from None
    try:
        model = resolve_reward(t, reward, dt=prog.system.dt)
        check_reward_fits(t, model)
    except (ValueError, TypeError) as err:
        raise ConfigError(str(err)) from None
    reward_text = model.text
    hyper = _hyperparameters(p.settings(algo, t.deadline), block, settings, algo, engine, block_algo=block.get("algo") or p.algo)
    given = {"steps": (steps, p.steps), "n_envs": (n_envs, p.n_envs), "eval_episodes": (eval_episodes, 1000),
             "seed": (seed, 0)}  # an argument, else the block's, else the default
    run = {k: v if v is not None else block.get(k, default) for k, (v, default) in given.items()}
    for name, value in run.items():
        problem = setting_problem(name, value)
        if problem is not None:
            raise ConfigError(problem)
    total, envs, run_seed, episodes = (int(run[k]) for k in ("steps", "n_envs", "seed", "eval_episodes"))
    if time_limit is not None and not (time_limit > 0 and time_limit < float("inf")):
        raise ConfigError(f"the time limit must be a positive number of seconds; got {time_limit}")
    demos = _demonstrations(prog, algo, demonstrations, p.demonstration_states(total))
    stall = 0
    from .demonstrations import searcher  # here: demonstrations imports this module

    if demonstrations is None and p.demonstrations_at(searcher(prog) == "planner") == "stall":  # when the run stalls
        demos, stall = 0, demos
    # The actor imitates the oracle's paths (SAC on sbx, known dynamics), the run's demonstrations
    # or as many as the preset's budget buys, at the start; the stall rule stays.
    asked, weight = imitation is not None, p.imitation if imitation is None else imitation
    if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not 0.0 <= weight < math.inf:
        raise ConfigError(f"the imitation's weight must be a number of 0 or more; got {weight!r}")
    imitation = 0.0
    if weight > 0:
        why = ("the oracle's paths need known dynamics (an ode or a map)" if searcher(prog) != "oracle"
               else "only SAC on the sbx engine imitates" if (algo, engine) != ("sac", "sbx") else None)
        if why is not None and asked:  # asked for, not the preset's: say why not
            raise ConfigError(f"--imitation: {why}; this run trains {algo.upper()} on {engine}")
        if why is None and demonstrations != 0:
            if demonstrations is None:
                demos, stall = min(int(p.imitation_states), total // max(1, int(p.demonstration_steps))), stall
            imitation = float(weight) if demos > 0 else 0.0
    if imitation > 0 and p.imitation_activation is not None and "activation_fn" not in hyper:
        hyper["activation_fn"] = p.imitation_activation  # measured with the imitation (the preset's why)
    restarts = p.failed_starts if failed_starts is None else failed_starts
    if isinstance(restarts, bool) or not isinstance(restarts, (int, float)) or not 0.0 <= restarts <= 1.0:
        raise ConfigError(f"failed starts must be a share between 0 and 1; got {restarts!r}")
    # The preset's rule for sparse goals, unless the run chose its demonstrations (0 included).
    late = 0 if demonstrations is not None else _demonstrations(prog, algo, None, p.late_demonstrations)
    # ... and where nothing is found, the actor imitates the paths the oracle then finds (SAC on
    # sbx, known dynamics; not where the run imitates from the start).
    sparse_imitation = (float(p.sparse_imitation) if late and imitation == 0 and searcher(prog) == "oracle"
                        and (algo, engine) == ("sac", "sbx") else 0.0)
    # The longer discount is for a policy that must find the detour on its own; one that imitates
    # the oracle's paths is shown it, and flies it faster at the shorter horizon (measured: puck
    # 99.1 / 65.4 / 7.9% against 77.6 / 54.6 / 7.4% with both).
    sparse_gamma = None
    chosen = "gamma" in block or "gamma" in (settings or {})
    if late and not sparse_imitation and p.sparse_horizon is not None and not chosen:
        longer = discount(t.deadline, p.sparse_horizon)
        sparse_gamma = longer if longer > float(hyper.get("gamma", 0.99)) else None
    if algo in OFF_POLICY:
        # Memory for what the run can fill, no more (the paper's buffer never drops a sample);
        # demonstrations are at most one episode per state.
        hyper["buffer_size"] = int(min(int(hyper.get("buffer_size", 1_000_000)),
                                       total + envs + (math.ceil((demos + stall) * max(1.0, p.demonstration_share
                                                                                       * p.demonstration_repeat)) + late)
                                       * (t.episode[1] + 1)))
    elif algo == "ppo":
        rollout = int(hyper.get("n_steps", 2048)) * envs
        batch = int(hyper.get("batch_size", 64))
        if batch > rollout:
            hyper["batch_size"] = rollout  # a mini-batch cannot exceed the rollout
    search = _policy_search(p, algo, engine, total, search_iterations, black_box=searcher(prog) != "oracle")
    every = max(envs, (total // max(1, p.validations)) // envs * envs)
    scaling = t.observe_scaling or p.observation_scaling
    sources = dict(zip(prog.system.state_names, observation_sources(prog.system, t.init_box, scaling)))
    return TrainConfig(
        task=t.name, algo=algo, engine=engine, reward=reward_text, seed=run_seed, preset=p.name, steps=total, n_envs=envs,
        torch_threads=p.torch_threads, observation_scaling=scaling, action_scaling=p.action_scaling,
        # With the time left in the observation the deadline is part of the state: an episode's
        # end is a true terminal (no bootstrapping past it). Without it the agent cannot tell, and
        # the time-out must be bootstrapped (stable-baselines3's TimeLimit.truncated handling).
        time_limit_terminal="time" in t.observe,
        validation_episodes=validation_states(total, p.validation_episodes), validation_seed=VALIDATION_SEED,
        validate_every=every,
        eval_episodes=episodes, hyper=hyper, time_limit=None if time_limit is None else float(time_limit),
        demonstrations=demos, late_demonstrations=late, stall_demonstrations=stall, sparse_gamma=sparse_gamma,
        observation_sources=sources,
        demonstration_share=p.demonstration_share, demonstration_repeat=p.demonstration_repeat,
        demonstration_seconds=p.demonstration_budget(time_limit, black_box=searcher(prog) == "planner"),
        failed_starts=float(restarts),
        imitation=imitation, sparse_imitation=sparse_imitation,
        imitation_seconds=p.demonstration_budget(time_limit, imitation=True) if imitation or sparse_imitation else None,
        imitation_states=int(p.imitation_states) if sparse_imitation else 0,
        failure_reward=_failure_reward(prog, t, model, hyper, p.failure_forever), plateau=p.plateau,
        plateau_after=p.plateau_after if p.plateau is not None else None, policy_search=search)


def _policy_search(p, algo: str, engine: str, steps: int, explicit: Optional[int],
                   black_box: bool) -> Optional[dict[str, Any]]:
    """The run's policy search settings (None: none): the preset's, with ``explicit`` iterations
    (refused where the actor cannot be searched), else at most one per ``search_steps`` steps and
    not on a black box: the swimmer's 16,384 rollouts of an iteration took 73 s (a compiled ODE's
    0.3 s), a thousand iterations most of a day."""
    if explicit is not None:
        if isinstance(explicit, bool) or not isinstance(explicit, int) or explicit < 0:
            raise ConfigError(f"the policy search's iterations must be a whole number, 0 or more; got {explicit!r}")
        if explicit and (algo, engine) not in SEARCHABLE:
            raise ConfigError(f"--search-iterations: the policy search perturbs the actor of SAC, TD3 or DDPG on the "
                              f"sbx engine; this run trains {algo.upper()} on {engine}")
    base = dict(p.policy_search or {})
    iterations = explicit if explicit is not None else (
        min(int(base.get("iterations", SearchSettings.iterations)), steps // max(1, p.search_steps))
        if base and not black_box else 0)
    if not iterations or (algo, engine) not in SEARCHABLE:
        return None
    return SearchSettings.from_dict({**base, "iterations": int(iterations)}).to_dict()


def _hyperparameters(preset: Mapping[str, Any], block: Mapping[str, Any], settings: Optional[Mapping[str, Any]],
                     algo: str, engine: str, block_algo: str) -> dict[str, Any]:
    """The preset's, the block's and the explicit settings merged (later stronger, ``policy_kwargs``'
    entries one setting each: :mod:`.hyper`) and checked against what ``algo`` takes on ``engine``.
    The block's settings of another algorithm are left out when the run trains another than the
    block's own (``block_algo``: an ``--algo`` that overrides it); the explicit ones must all apply."""
    own = {k: v for k, v in block.items() if k not in _RUN_KEYS}
    if settings is not None and not isinstance(settings, Mapping):
        raise ConfigError(f"settings must be a mapping of setting names to values; got {type(settings).__name__}")
    try:
        layers = [_hyper.normalise(preset, f"the {algo} preset"), _hyper.normalise(own, "the train block"),
                  _hyper.normalise(dict(settings or {}), "settings")]
        foreign = frozenset(layers[1]) if block_algo != algo else frozenset()
        return _hyper.check(algo, engine, _hyper.merge(*layers), foreign_ok=foreign)
    except ValueError as err:
        raise ConfigError(str(err)) from None


def _failure_reward(prog, task, reward_model, hyper: Mapping[str, Any], forever: bool) -> Optional[float]:
    """With ``forever``, a failure step earns the reward's floor for every step after it,
    ``floor / (1 - gamma)``: the least any episode that goes on could earn, so that ending an
    episode by leaving the state space (or by ``avoid``) is never the learner's way out of a state
    it cannot solve. None otherwise, or where the reward has no floor (``distance``)."""
    from asap_dsl.rewards import Reward

    if not forever:
        return None
    floor = Reward(task, prog.regions, prog.system.n_state, 1, reward_model).floor
    gamma = float(hyper.get("gamma", 0.99))
    if floor is None or not 0.0 <= gamma < 1.0:
        return None
    return float(floor / (1.0 - gamma))


def _demonstrations(prog, algo: str, explicit: Optional[int], preset: int) -> int:
    """The demonstration states of a run: the explicit count (refused where there can be none),
    else the preset's where there can be some, else 0."""
    from .demonstrations import unavailable  # it imports this module

    why = unavailable(prog, algo)
    if explicit is None:
        return 0 if why else int(preset)
    if isinstance(explicit, bool) or int(explicit) != explicit or explicit < 0:
        raise ConfigError(f"demonstrations must be a whole number, 0 or more; got {explicit!r}")
    if explicit and why:
        raise ConfigError(f"demonstrations cannot be used here: {why}")
    return int(explicit)
