"""Hyperparameters: which keywords an algorithm takes on an engine, how the layers of a run's
settings (preset, ``train { ... }`` block, explicit ``settings=``) merge, and how the result
becomes the model's constructor keywords and ``policy_kwargs``.

A setting may be any keyword of the algorithm's constructor or of its ``MlpPolicy`` in the
installed library of the engine that trains it (stable-baselines3, or sbx), as rl-zoo3's
hyperparameter files write them, flat (``log_std_init = -3.67``) or inside ``policy_kwargs``.
The keywords are read from the library's source with :mod:`ast`, without importing it: importing
sbx loads JAX, which a process that forks workers later must not have (:mod:`.engines`).

Besides the libraries' keywords the language has its own: ``target_entropy_per_action`` (SAC:
the target entropy per action dimension), ``action_noise`` as a number (TD3/DDPG: the std of
Gaussian exploration noise over the action half-range) and ``activation_fn`` by name (``relu``,
``tanh``, ...: each engine's own function). Every problem is a
:class:`~asap_dsl.backends.rl.config.ConfigError` sentence (raised here as ``ValueError``; the
configuration wraps it).
"""

from __future__ import annotations

import ast
import importlib.util
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping, Optional

from asap_dsl.checker_common import ALGORITHMS, setting_problem
from asap_dsl.diagnostics import closest

__all__ = ["ACTIVATIONS", "Keywords", "keywords", "merge", "normalise", "split"]

# What the run sets itself: never a setting.
_RUN_OWN = frozenset({"self", "policy", "env", "seed", "device", "tensorboard_log", "verbose", "_init_setup_model"})
_POLICY_OWN = frozenset({"self", "observation_space", "action_space", "lr_schedule"})
#: The language's own settings, and the algorithms that take them.
EXTENSIONS = {"target_entropy_per_action": ("sac",)}
#: Policy keywords an engine's library lacks and the project adds: stable-baselines3's SAC, TD3
#: and DDPG normalise their critics' hidden layers as sbx's do (``sb3._layer_norm_policy``).
POLICY_EXTENSIONS = {("sb3", algo): frozenset({"layer_norm"}) for algo in ("sac", "td3", "ddpg")}
#: ``activation_fn`` by name: torch.nn's class for stable-baselines3, flax.linen's function for sbx.
ACTIVATIONS = {"relu": ("ReLU", "relu"), "tanh": ("Tanh", "tanh"), "elu": ("ELU", "elu"),
               "leaky_relu": ("LeakyReLU", "leaky_relu"), "gelu": ("GELU", "gelu"), "silu": ("SiLU", "silu"),
               "sigmoid": ("Sigmoid", "sigmoid")}
# A stronger layer's keyword replaces a weaker layer's other spelling of the same thing.
_SAME_THING = {"target_entropy": "target_entropy_per_action", "target_entropy_per_action": "target_entropy"}
_ENGINE_MODULES = {"sb3": "stable_baselines3", "sbx": "sbx"}


@dataclass(frozen=True)
class Keywords:
    """The keywords an algorithm's constructor and its ``MlpPolicy`` take (the run's own left out)."""

    constructor: frozenset[str]
    policy: frozenset[str]

    @property
    def all(self) -> frozenset[str]:
        return self.constructor | self.policy


# ------------------------------------------------------------------------------ reading the source
def _package_dir(top: str) -> Optional[Path]:
    spec = importlib.util.find_spec(top)  # a top-level name: found without importing it
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(list(spec.submodule_search_locations)[0])


def _module_path(module: str) -> Optional[Path]:
    top, *rest = module.split(".")
    base = _package_dir(top)
    if base is None:
        return None
    p = base.joinpath(*rest)
    for candidate in (p / "__init__.py", p.with_suffix(".py")):
        if candidate.is_file():
            return candidate
    return None


@lru_cache(maxsize=None)
def _parsed(module: str) -> Optional[ast.Module]:
    path = _module_path(module)
    return None if path is None else ast.parse(path.read_text(encoding="utf-8"))


def _absolute(module: str, node: ast.ImportFrom, is_package: bool) -> str:
    if not node.level:
        return node.module or ""
    parts = module.split(".")
    base = parts if is_package else parts[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _find_class(module: str, name: str, depth: int = 0) -> Optional[tuple[str, ast.ClassDef]]:
    """The definition of class ``name`` as ``module`` sees it: defined there, assigned from another
    name (``MlpPolicy = SACPolicy``) or imported (``from sbx.sac import SAC``)."""
    tree = _parsed(module)
    if tree is None or depth > 12:
        return None
    path = _module_path(module)
    is_package = path is not None and path.name == "__init__.py"
    for node in tree.body:
        if isinstance(node, ast.ClassDef) and node.name == name:
            return module, node
    for node in tree.body:
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Name) and \
                any(isinstance(t, ast.Name) and t.id == name for t in node.targets):
            return _find_class(module, node.value.id, depth + 1)
        if isinstance(node, ast.ImportFrom):
            for alias in node.names:
                if (alias.asname or alias.name) == name:
                    return _find_class(_absolute(module, node, is_package), alias.name, depth + 1)
    return None


def _init_keywords(module: str, cls: ast.ClassDef, depth: int = 0) -> Optional[set[str]]:
    """The keyword names of the class's ``__init__`` (its base's where it has none)."""
    for node in cls.body:
        if isinstance(node, ast.FunctionDef) and node.name == "__init__":
            a = node.args
            if a.kwarg is not None:
                return None  # **kwargs: whatever it forwards cannot be told from here
            return {x.arg for x in (*a.posonlyargs, *a.args, *a.kwonlyargs)}
    if depth < 8 and cls.bases and isinstance(cls.bases[0], ast.Name):
        base = _find_class(module, cls.bases[0].id)
        if base is not None:
            return _init_keywords(*base, depth=depth + 1)
    return None


def _policy_class(module: str, cls: ast.ClassDef) -> Optional[tuple[str, ast.ClassDef]]:
    for node in cls.body:
        target = node.target if isinstance(node, ast.AnnAssign) else (
            node.targets[0] if isinstance(node, ast.Assign) and len(node.targets) == 1 else None)
        if isinstance(target, ast.Name) and target.id == "policy_aliases" and isinstance(node.value, ast.Dict):
            for k, v in zip(node.value.keys, node.value.values):
                if isinstance(k, ast.Constant) and k.value == "MlpPolicy" and isinstance(v, ast.Name):
                    return _find_class(module, v.id)
    return None


def _inspected(engine: str, algo: str) -> Keywords:
    """The keywords by importing the class (where its source cannot be read)."""
    import inspect

    from .engines import _configure_jax

    if engine == "sbx":
        _configure_jax()
    cls = getattr(importlib.import_module(_ENGINE_MODULES[engine]), algo.upper())
    policy = cls.policy_aliases["MlpPolicy"]
    return Keywords(frozenset(inspect.signature(cls.__init__).parameters) - _RUN_OWN,
                    frozenset(inspect.signature(policy.__init__).parameters) - _POLICY_OWN)


@lru_cache(maxsize=None)
def keywords(engine: str, algo: str) -> Keywords:
    """What ``algo``'s constructor and ``MlpPolicy`` take in the installed library of ``engine``
    (``sb3`` or ``sbx``), the language's own settings included."""
    own = frozenset(k for k, algos in EXTENSIONS.items() if algo in algos)
    found = _find_class(_ENGINE_MODULES[engine], algo.upper())
    ctor = policy = None
    if found is not None:
        ctor = _init_keywords(*found)
        pol = _policy_class(*found)
        policy = _init_keywords(*pol) if pol is not None else None
    if ctor is None or policy is None:
        k = _inspected(engine, algo)
    else:
        k = Keywords(frozenset(ctor) - _RUN_OWN, frozenset(policy) - _POLICY_OWN)
    return Keywords(k.constructor | own, k.policy | POLICY_EXTENSIONS.get((engine, algo), frozenset()))


# ------------------------------------------------------------------------------ the layers
def _storable(value: Any) -> bool:
    if value is None or isinstance(value, (bool, int, float, str)):
        return True
    if isinstance(value, (list, tuple)):
        return all(_storable(v) for v in value)
    if isinstance(value, Mapping):
        return all(isinstance(k, str) and _storable(v) for k, v in value.items())
    return False


def normalise(layer: Mapping[str, Any], where: str) -> dict[str, Any]:
    """One layer's settings with ``policy_kwargs``' entries flattened into it (a policy keyword
    is one setting wherever it is written), lists for tuples. ``where`` names the layer in a
    message (``the train block``)."""
    out: dict[str, Any] = {}
    nested = layer.get("policy_kwargs")
    if nested is not None and not isinstance(nested, Mapping):
        raise ValueError(f"policy_kwargs in {where} must be named values, such as {{net_arch: [64, 64]}}; "
                         f"got {nested!r}")
    for k, v in layer.items():
        if k != "policy_kwargs":
            out[k] = v
    for k, v in (nested or {}).items():
        if k in out and out[k] != v:
            raise ValueError(f"{where} gives {k} twice, {out[k]!r} and {v!r} in policy_kwargs; keep one")
        out[k] = v
    for k, v in out.items():
        if not _storable(v):
            raise ValueError(f"the setting {k} = {v!r} cannot be stored in the run's manifest: give a number, "
                             "true or false, a text, a list or named values"
                             + (f" (activation_fn by name: {', '.join(ACTIVATIONS)})" if k == "activation_fn" else ""))
    return {k: list(v) if isinstance(v, tuple) else v for k, v in out.items()}


def merge(*layers: Mapping[str, Any]) -> dict[str, Any]:
    """Layers merged, the later stronger (each already :func:`normalise`\\ d): a stronger layer's
    keyword replaces a weaker layer's, and a weaker layer's other spelling of it
    (``target_entropy`` / ``target_entropy_per_action``)."""
    out: dict[str, Any] = {}
    for layer in layers:
        for k, v in layer.items():
            other = _SAME_THING.get(k)
            if other is not None and other not in layer:
                out.pop(other, None)
            out[k] = v
    return out


def _algos_with(key: str) -> list[str]:
    """The algorithms of the language that take ``key`` on some installed engine."""
    from .engines import ENGINES, get_engine

    found = []
    for algo in ALGORITHMS:
        for e in ENGINES:
            eng = get_engine(e)
            if eng.runs(algo) and eng.available() and key in keywords(e, algo).all:
                found.append(algo)
                break
    return found


def check(algo: str, engine: str, hyper: Mapping[str, Any], foreign_ok: frozenset[str] = frozenset()) -> dict:
    """``hyper`` with what ``algo`` on ``engine`` takes; ``ValueError`` (one sentence) for a
    keyword it does not take: did-you-mean, or the engine or algorithm that does. Keywords in
    ``foreign_ok`` that another algorithm takes are left out instead (a spec's block written
    for its own algorithm, trained with another)."""
    from .engines import ENGINES, get_engine

    known = keywords(engine, algo)
    out: dict[str, Any] = {}
    for k, v in hyper.items():
        if k in known.all:
            _check_value(k, v)
            out[k] = v
            continue
        others = [e for e in ENGINES if e != engine and get_engine(e).runs(algo) and get_engine(e).available()
                  and k in keywords(e, algo).all]
        if others:
            raise ValueError(f"the {engine} engine's {algo.upper()} has no setting '{k}'; the {others[0]} engine's "
                             f"has it: train with --engine {others[0]} (engine=\"{others[0]}\")")
        algos = [a for a in _algos_with(k) if a != algo]
        if algos:
            if k in foreign_ok:
                continue
            raise ValueError(f"{algo} has no setting '{k}' ({', '.join(algos)} {'has' if len(algos) == 1 else 'have'} it)")
        sug = closest(k, sorted(known.all))
        raise ValueError(f"unknown training setting '{k}' for {algo} on the {engine} engine"
                         + (f"; did you mean '{sug}'?" if sug else ""))
    return out


def _check_value(key: str, value: Any) -> None:
    """The values whose form both engines parse alike, and the numbers' ranges of
    :data:`~asap_dsl.checker_common.SETTING_RANGES` (the rest their constructors check)."""
    if key == "ent_coef" and isinstance(value, str):
        head, _, init = value.partition("_")
        ok = head == "auto"
        if ok and init:
            try:
                ok = float(init) > 0
            except ValueError:
                ok = False
        if not ok:
            raise ValueError(f"ent_coef = {value!r}: write a number, \"auto\", or \"auto_0.1\" (learned, from 0.1)")
    if key == "activation_fn" and value not in ACTIVATIONS:
        sug = closest(str(value), ACTIVATIONS)
        raise ValueError(f"unknown activation_fn '{value}'" + (f"; did you mean '{sug}'?" if sug else
                                                                f"; choose {', '.join(ACTIVATIONS)}"))
    problem = setting_problem(key, value)
    if problem is not None:
        raise ValueError(problem)
    if key == "net_arch":
        _check_layers(value)
    if key == "target_entropy_per_action" and value is not None and \
            (isinstance(value, bool) or not isinstance(value, (int, float))):
        raise ValueError(f"{key} takes a number; got {value!r}")


#: The most weights between two hidden layers of one network: 10^8 (400 MB in float32, and the
#: optimiser keeps two more copies), far past any controller's network and inside a machine's memory.
MAX_LAYER_WEIGHTS = 100_000_000


def _check_layers(value: Any) -> None:
    """``net_arch``: hidden layer widths, a list of positive whole numbers (or named lists, such as
    ``{pi: [64, 64], qf: [256, 256]}``), small enough to be built."""
    lists = value.values() if isinstance(value, Mapping) else [value]
    for widths in lists:
        if not isinstance(widths, (list, tuple)) or not all(
                isinstance(w, int) and not isinstance(w, bool) and w >= 1 for w in widths):
            raise ValueError(f"net_arch = {value!r}: give the hidden layers' widths as positive whole numbers, "
                             "such as [64, 64] or {pi: [64, 64], qf: [256, 256]}")
        big = max((a * b for a, b in zip(widths, widths[1:])), default=0)
        if big > MAX_LAYER_WEIGHTS:
            raise ValueError(f"net_arch = {value!r}: two consecutive layers need {big:,} weights, more than "
                             f"{MAX_LAYER_WEIGHTS:,} (400 MB each, before the optimiser's copies); use narrower layers")


def split(engine: str, algo: str, hyper: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """The constructor's keywords and the policy's (``policy_kwargs``) of checked settings; a
    keyword both take (``use_sde``) goes to the constructor, which passes it on."""
    known = keywords(engine, algo)
    ctor = {k: v for k, v in hyper.items() if k in known.constructor or k not in known.policy}
    policy = {k: v for k, v in hyper.items() if k not in ctor}
    if "train_freq" in ctor and isinstance(ctor["train_freq"], list):  # (1, "episode"): the libraries want a tuple
        ctor["train_freq"] = tuple(ctor["train_freq"])
    name = policy.get("activation_fn")
    if isinstance(name, str):
        policy["activation_fn"] = _activation(engine, name)
    return ctor, policy


def _activation(engine: str, name: str):
    torch_name, flax_name = ACTIVATIONS[name]
    if engine == "sbx":
        import flax.linen

        return getattr(flax.linen, flax_name)
    import torch.nn

    return getattr(torch.nn, torch_name)
