"""What ``asapc tune`` searches: each algorithm's hyperparameters, as Optuna samples them, turned
into ``train { ... }`` settings.

The ranges follow rl-zoo3's samplers (learning rate log-uniform from 1e-5, ``1 - gamma``
log-uniform, batch sizes in powers of two, ``tau`` log-uniform, a few network widths, PPO's
rollout length, epochs, GAE, entropy and clipping), narrowed where a short tuning budget or the
task's own scale calls for it: ``learning_starts`` and PPO's rollout are bounded by the trial's
steps (a rollout longer than the budget never updates), and SAC searches the language's
``target_entropy_per_action``. Every value is rounded to three significant digits (``gamma`` to
its fifth decimal) *before* the trial trains, so the block that is printed is the one that was
scored. Only settings the algorithm takes on the engine are searched (:mod:`asap_dsl.backends.rl.hyper`).
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

__all__ = ["SEARCHED", "SpaceContext", "sample", "settings_id"]

#: The network shapes searched (``net_arch``), by the name Optuna stores.
_NETS = {"32x32": [32, 32], "64x64": [64, 64], "128x128": [128, 128], "256x256": [256, 256], "400x300": [400, 300]}
_OFF_POLICY_NETS = ("32x32", "64x64", "128x128", "256x256", "400x300")
_ON_POLICY_NETS = ("32x32", "64x64", "128x128", "256x256")


@dataclass(frozen=True)
class SpaceContext:
    """What bounds the ranges: the trial's algorithm and engine, its steps and environments."""

    algo: str
    engine: str
    steps: int
    n_envs: int


def _sig(x: float, digits: int = 3) -> float:
    """``x`` to ``digits`` significant digits (a value a block shows as written)."""
    return float(f"{x:.{digits}g}")


def _off_policy(trial, ctx: SpaceContext) -> dict[str, Any]:
    low = max(1, min(100, ctx.steps // 10))
    high = max(low + 1, min(10_000, ctx.steps // 4))
    out = {
        "learning_rate": _sig(trial.suggest_float("learning_rate", 1e-5, 3e-3, log=True)),
        "batch_size": trial.suggest_categorical("batch_size", [32, 64, 128, 256, 512]),
        "gamma": round(1.0 - trial.suggest_float("one_minus_gamma", 1e-3, 0.05, log=True), 5),
        "tau": _sig(trial.suggest_float("tau", 1e-3, 0.08, log=True)),
        "train_freq": trial.suggest_int("train_freq", 1, 8),
        "gradient_steps": trial.suggest_int("gradient_steps", 1, 8),
        "learning_starts": _sig(trial.suggest_int("learning_starts", low, high, log=True), 2),
        "net_arch": _NETS[trial.suggest_categorical("net_arch", list(_OFF_POLICY_NETS))],
    }
    out["learning_starts"] = int(out["learning_starts"])
    if ctx.algo == "sac":
        out["target_entropy_per_action"] = _sig(trial.suggest_float("target_entropy_per_action", -4.0, -0.25), 2)
    else:  # TD3, DDPG: Gaussian exploration noise over the action's half-range
        out["action_noise"] = _sig(trial.suggest_float("action_noise", 0.02, 0.5, log=True), 2)
    return out


def _rollouts(ctx: SpaceContext, choices: tuple[int, ...]) -> list[int]:
    """The rollout lengths (per environment) that leave room for at least 4 updates in the budget."""
    fit = [n for n in choices if n * ctx.n_envs * 4 <= ctx.steps]
    return fit or [choices[0]]


def _on_policy(trial, ctx: SpaceContext) -> dict[str, Any]:
    out: dict[str, Any] = {
        "learning_rate": _sig(trial.suggest_float("learning_rate", 1e-5, 3e-3, log=True)),
        "gamma": round(1.0 - trial.suggest_float("one_minus_gamma", 1e-3, 0.05, log=True), 5),
        "gae_lambda": round(1.0 - trial.suggest_float("one_minus_gae_lambda", 1e-4, 0.1, log=True), 5),
        "ent_coef": _sig(trial.suggest_float("ent_coef", 1e-8, 0.1, log=True)),
        "max_grad_norm": _sig(trial.suggest_float("max_grad_norm", 0.3, 2.0), 2),
        "net_arch": _NETS[trial.suggest_categorical("net_arch", list(_ON_POLICY_NETS))],
        "activation_fn": trial.suggest_categorical("activation_fn", ["tanh", "relu"]),
    }
    if ctx.algo == "ppo":
        out["n_steps"] = trial.suggest_categorical("n_steps", _rollouts(ctx, (16, 32, 64, 128, 256, 512, 1024, 2048)))
        out["batch_size"] = trial.suggest_categorical("batch_size", [32, 64, 128, 256, 512])
        out["n_epochs"] = trial.suggest_categorical("n_epochs", [1, 5, 10, 20])
        out["clip_range"] = trial.suggest_categorical("clip_range", [0.1, 0.2, 0.3, 0.4])
    else:  # A2C: short rollouts, one update each
        out["n_steps"] = trial.suggest_categorical("n_steps", _rollouts(ctx, (5, 8, 16, 32, 64, 128)))
    return out


_SAMPLERS: dict[str, Callable] = {"sac": _off_policy, "td3": _off_policy, "ddpg": _off_policy,
                                  "ppo": _on_policy, "a2c": _on_policy}

#: The settings each algorithm's search sets (a written block keeps the task's others).
SEARCHED = {
    "sac": ("learning_rate", "batch_size", "gamma", "tau", "train_freq", "gradient_steps", "learning_starts",
            "net_arch", "target_entropy_per_action"),
    "td3": ("learning_rate", "batch_size", "gamma", "tau", "train_freq", "gradient_steps", "learning_starts",
            "net_arch", "action_noise"),
    "ppo": ("learning_rate", "gamma", "gae_lambda", "ent_coef", "max_grad_norm", "net_arch", "activation_fn",
            "n_steps", "batch_size", "n_epochs", "clip_range"),
    "a2c": ("learning_rate", "gamma", "gae_lambda", "ent_coef", "max_grad_norm", "net_arch", "activation_fn", "n_steps"),
}
SEARCHED["ddpg"] = tuple(k if k != "target_entropy_per_action" else "action_noise" for k in SEARCHED["td3"])


def sample(trial, ctx: SpaceContext) -> dict[str, Any]:
    """One trial's settings by their ``train { ... }`` names (Optuna's ``trial`` asked define-by-run),
    only those ``ctx.algo`` takes on ``ctx.engine``."""
    from asap_dsl.backends.rl import hyper

    settings = _SAMPLERS[ctx.algo](trial, ctx)
    known = hyper.keywords(ctx.engine, ctx.algo).all
    return {k: v for k, v in settings.items() if k in known}


def settings_id(settings: Mapping[str, Any]) -> str:
    """A short name for a trial's settings (its run directory): the same settings, the same name, so
    a trial asked again after an interruption continues the run it had begun."""
    text = json.dumps({k: settings[k] for k in sorted(settings)}, sort_keys=True, allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def finite(x: Any) -> bool:
    """A score Optuna can be told (a number, not NaN or infinite)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
