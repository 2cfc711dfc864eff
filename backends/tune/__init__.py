"""Hyperparameter tuning of a task's training (``asapc tune``): Optuna over the engine's
hyperparameters (:mod:`.space`), each trial a training run scored on its validation states
(:mod:`.trial`), the study and its directory (:mod:`.study`), the same search through Ray Tune
(:mod:`.ray_search`), and the winning ``train { ... }`` block written into the spec (:mod:`.block`).

    from asap_dsl.backends.tune import Tuning
    tuning = Tuning.open("examples/double_integrator.asap", "park", steps=5000)
    result = tuning.search(trials=10, time_limit=None, tell=lambda event, data: None)

The names load on first use: Optuna and Ray are imported only by a tuning.
"""

from __future__ import annotations

import importlib

_WHERE = {
    "block": ("BlockError", "format_block", "merged_block", "write_block"),
    "ray_search": ("search_ray",),
    "space": ("SEARCHED", "SpaceContext", "sample", "settings_id"),
    "study": ("TrialRecord", "TuneError", "TuneResult", "TuneSetup", "Tuning"),
    "trial": ("TrialJob", "TrialOutcome", "run_trial"),
}
_MODULE = {name: module for module, names in _WHERE.items() for name in names}

__all__ = sorted(_MODULE) + ["ClusterError"]


def __getattr__(name: str):
    if name == "ClusterError":  # what --ray raises when the cluster cannot be joined
        from ..compare.cluster import ClusterError

        return ClusterError
    if name in _MODULE:
        return getattr(importlib.import_module(f"{__name__}.{_MODULE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
