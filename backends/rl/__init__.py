"""Reinforcement learning with stable-baselines3's API: presets, the training configuration, the
engines that train (stable-baselines3 on torch, sbx on JAX), the SB3 glue (observation and action
scaling, model building), training runs and their evaluation.

    from asap_dsl.backends.rl import train, evaluate

The names load on first use: the command line reads the presets without importing torch.
"""

from __future__ import annotations

import importlib

_WHERE = {
    "config": ("VALIDATION_SEED", "ConfigError", "TrainConfig", "resolve_config"),
    "engines": ("ENGINES", "Engine", "get_engine"),
    "evaluation": ("Evaluation", "LoadedRun", "evaluate", "load_run", "summarise"),
    "presets": ("ALGORITHMS", "DEFAULT", "OFF_POLICY", "PAPER", "PRESETS", "Preset", "get_preset"),
    "sb3": ("PolicyController", "Scaling", "ScaledVecEnv", "build_model", "load_model"),
    "session": ("CHECKPOINT_SECONDS",),
    "training": ("TrainProgress", "TrainResult", "train", "validation_score"),
}
_MODULE = {name: module for module, names in _WHERE.items() for name in names}

__all__ = sorted(_MODULE)


def __getattr__(name: str):
    if name in _MODULE:
        return getattr(importlib.import_module(f"{__name__}.{_MODULE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
