"""What the parts of the checker share: the tables of settings, the kinds of names, the state
of one check (:class:`CheckState`), the exception that leaves a broken part out, and small
helpers (see :mod:`asap_dsl.checker`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Optional

from . import ast
from .diagnostics import Collector, Span
from .model import ActionVar, FormulaModel, RegionModel, StateVar

ALGORITHMS = ("sac", "td3", "ddpg", "ppo", "a2c")
#: The reward kinds, each with its settings and their defaults (None: no default; a ``rho``
#: without a window is over the whole episode). The language's table: specs and ``--reward``.
REWARDS: dict[str, dict[str, Optional[float]]] = {
    "asap": {}, "rho": {"window": None}, "distance": {"lambda_t": 1.0, "lambda_o": 1.0, "base": 0.0}}
INTEGRATORS = {"rk4": ("substeps",), "euler": ("substeps",), "exact": ()}
#: The settings of a ``train { ... }`` block that are the run's own, and what each takes.
RUN_SETTINGS = {"algo": "str", "steps": "int", "seed": "int", "preset": "str", "n_envs": "int", "eval_episodes": "int"}
#: The other settings: the keywords of the algorithms' constructors and of their policies, in
#: stable-baselines3 and in sbx, every algorithm (those the run sets itself, such as ``env`` and
#: ``seed``, left out), and the language's own ``target_entropy_per_action`` (SAC) and
#: ``action_noise`` (a number: the std of TD3/DDPG's Gaussian noise over the action half-range).
#: Which of them the run's algorithm and engine take is checked when it trains, against the
#: installed constructor (:mod:`asap_dsl.backends.rl.hyper`); tests/test_train_settings.py keeps
#: this list equal to the installed libraries'. The checker has it by name: no import of them.
HYPERPARAMETERS = (
    "action_noise", "activation_fn", "actor_class", "batch_size", "buffer_size", "clip_mean", "clip_range",
    "clip_range_vf", "critic_class", "dropout_rate", "ent_coef", "features_extractor_class",
    "features_extractor_kwargs", "full_std", "gae_lambda", "gamma", "gradient_steps", "layer_norm",
    "learning_rate", "learning_starts", "log_std_init", "max_grad_norm", "n_critics", "n_epochs", "n_steps",
    "net_arch", "normalize_advantage", "normalize_images", "optimize_memory_usage", "optimizer_class",
    "optimizer_kwargs", "ortho_init", "param_resets", "policy_delay", "policy_kwargs", "qf_learning_rate",
    "replay_buffer_class", "replay_buffer_kwargs", "rms_prop_eps", "rollout_buffer_class", "rollout_buffer_kwargs",
    "sde_sample_freq", "share_features_extractor", "squash_output", "stats_window_size", "target_entropy",
    "target_entropy_per_action", "target_kl", "target_noise_clip", "target_policy_noise", "target_update_interval",
    "tau", "train_freq", "use_expln", "use_rms_prop", "use_sde", "use_sde_at_warmup", "vector_critic_class",
    "vf_coef",
)
TRAIN_SETTINGS = {**RUN_SETTINGS, **{k: "value" for k in HYPERPARAMETERS}}


@dataclass(frozen=True)
class Allowed:
    """The numbers a setting takes: from ``low`` to ``high`` (each end in or out), whole or not;
    ``number_only``: a text or a list is no value of it either (``learning_rate = fast``)."""

    low: float
    high: float = float("inf")
    low_in: bool = True
    high_in: bool = True
    whole: bool = False
    number_only: bool = True

    def __str__(self) -> str:
        lo, hi = f"{self.low:g}", f"{self.high:,.0f}" if self.whole else f"{self.high:g}"
        if self.whole:
            return f"a whole number from {lo} to {hi}" if self.high < math.inf else f"a whole number, {lo} or more"
        if self.high == math.inf:
            return f"a number of {lo} or more" if self.low_in else f"a number above {lo}"
        if self.low_in and self.high_in:
            return f"a number from {lo} to {hi}"
        return f"a number in {'[' if self.low_in else '('}{lo}, {hi}{']' if self.high_in else ')'}"


_POSITIVE, _NATURAL, _COUNT = Allowed(0.0, low_in=False), Allowed(0.0), Allowed(1.0, whole=True)
#: The numbers each setting of a ``train`` block takes where the libraries would take anything
#: and fail later or train nonsense (γ = 2, a batch of 0, a NaN learning rate): lint checks the
#: block, and a run its merged settings (the Python API's too) with :func:`setting_problem`.
#: -1 is stable-baselines3's "as many as the steps collected" (gradient_steps) and "once per
#: rollout" (sde_sample_freq).
SETTING_RANGES: dict[str, Allowed] = {
    "steps": _COUNT, "n_envs": _COUNT, "eval_episodes": _COUNT, "seed": Allowed(0.0, 2.0 ** 32 - 1, whole=True),
    "gamma": Allowed(0.0, 1.0), "gae_lambda": Allowed(0.0, 1.0), "tau": Allowed(0.0, 1.0, low_in=False),
    "dropout_rate": Allowed(0.0, 1.0, high_in=False, number_only=False),
    "learning_rate": _POSITIVE, "qf_learning_rate": _POSITIVE, "clip_range": _POSITIVE, "max_grad_norm": _POSITIVE,
    "rms_prop_eps": _POSITIVE, "clip_range_vf": Allowed(0.0, low_in=False, number_only=False),
    "target_kl": Allowed(0.0, low_in=False, number_only=False),
    "vf_coef": _NATURAL, "target_policy_noise": _NATURAL, "target_noise_clip": _NATURAL, "action_noise": _NATURAL,
    "ent_coef": Allowed(0.0, number_only=False),  # or "auto", "auto_0.1"
    "batch_size": _COUNT, "buffer_size": _COUNT, "n_steps": _COUNT, "n_epochs": _COUNT, "n_critics": _COUNT,
    "policy_delay": _COUNT, "target_update_interval": _COUNT, "stats_window_size": _COUNT,
    "train_freq": Allowed(1.0, whole=True, number_only=False),  # or [1, "episode"]
    "learning_starts": Allowed(0.0, whole=True), "gradient_steps": Allowed(-1.0, whole=True),
    "sde_sample_freq": Allowed(-1.0, whole=True),
}


def setting_problem(name: str, value: Any) -> Optional[str]:
    """What is wrong with ``value`` for the training setting ``name`` (its :data:`SETTING_RANGES`),
    in words; None when nothing is, or the setting has no range here."""
    allowed = SETTING_RANGES.get(name)
    if allowed is None or value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"'{name}' takes {allowed}, not {value!r}" if allowed.number_only else None
    x = float(value)
    inside = (x > allowed.low or (allowed.low_in and x == allowed.low)) and \
        (x < allowed.high or (allowed.high_in and x == allowed.high))
    if inside and (not allowed.whole or x.is_integer()):
        return None
    return f"'{name}' must be {allowed}, not {value:g}" if isinstance(value, float) else f"'{name}' must be {allowed}, not {value:,}"


OBSERVE_ITEMS = ("state", "time")
#: `observe scaling = ...`: the box each state entry of the policy's input is scaled from
#: (:mod:`asap_dsl.observation`).
OBSERVATION_SCALINGS = ("init", "state", "none")
_MAX_STEPS = 1e9  # a time of more steps than this is a typo, not an episode
_FUTURE_TO_PAST = {"always": "historically", "eventually": "once", "until": "since"}

# Kinds of names.
CONST, STATE, ACTION, LET, REGION, FORMULA, TASK, SYSTEM = (
    "constant", "state", "action", "let", "region", "formula", "task", "system")


class _Unresolved(Exception):
    """A sub-expression had errors (already reported); the enclosing item is left out."""


@dataclass
class CheckState:
    """What the checker knows so far about one module, shared by its parts: where problems go
    (``diag``), every declared name and its kind, the names used, and the checked constants,
    states, actions, lets, dt, regions and formulas. Each part reads and adds what it checks."""

    module: ast.Module
    source: str
    diag: Collector
    kinds: dict[str, tuple[str, Span]] = field(default_factory=dict)
    used: set[str] = field(default_factory=set)
    consts: dict[str, float] = field(default_factory=dict)
    const_failed: set[str] = field(default_factory=set)  # constants (and dt) whose value had errors
    dt: Optional[float] = None
    steps_only: bool = False  # a map without `dt`: its times are steps, and nothing converts seconds
    states: list[StateVar] = field(default_factory=list)
    actions: list[ActionVar] = field(default_factory=list)
    lets: dict[str, ast.Expr] = field(default_factory=dict)
    action_lets: dict[str, str] = field(default_factory=dict)  # a let that reads actions -> one it reads
    regions: dict[str, RegionModel] = field(default_factory=dict)
    formulas: dict[str, FormulaModel] = field(default_factory=dict)

    def declared_here(self, name: str, span: Span) -> bool:
        """True if the declaration of ``name`` at ``span`` is the one that counts (not a repeat)."""
        return self.kinds.get(name, (None, None))[1] == span


def each(fn: Callable[[Any], Any], items: Iterable) -> list:
    """``fn`` on every item, each reporting its own problems: the results, or :class:`_Unresolved`
    once all have been tried if any failed (so that one bad part does not hide the others)."""
    out, failed = [], False
    for item in items:
        try:
            out.append(fn(item))
        except _Unresolved:
            failed = True
    if failed:
        raise _Unresolved
    return out


def dependency_order(names: list[str], deps: Callable[[str], Iterable[str]]) -> tuple[list[str], list[str]]:
    """``names`` ordered so that each comes after those it depends on, and the names at which a
    cycle was found. A name on a cycle, or depending on one, is left out of the order. A
    depth-first search with an explicit stack: a chain of definitions may be as long as the file."""
    VISITING, DONE, FAILED = 1, 2, 3
    state: dict[str, int] = {}
    order: list[str] = []
    cyclic: list[str] = []
    for root in names:
        if root in state:
            continue
        state[root] = VISITING
        stack = [(root, iter(deps(root)))]
        failed: set[str] = set()
        while stack:
            name, pending = stack[-1]
            for d in pending:
                seen = state.get(d)
                if seen is None:
                    state[d] = VISITING
                    stack.append((d, iter(deps(d))))
                    break
                if seen == VISITING:  # back to a name being defined: a cycle through it
                    if d not in cyclic:
                        cyclic.append(d)
                    failed.add(name)
                elif seen == FAILED:
                    failed.add(name)
            else:
                stack.pop()
                if name in failed:
                    state[name] = FAILED
                    if stack:
                        failed.add(stack[-1][0])
                else:
                    state[name] = DONE
                    order.append(name)
    return order, cyclic


def _a(word: str) -> str:
    """``word`` with its article: a state, an action."""
    return ("an " if word[:1] in "aeiou" else "a ") + word


