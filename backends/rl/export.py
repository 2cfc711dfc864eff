"""``asapc export``: a trained run's deterministic policy as one self-contained file, ONNX or
TorchScript, that maps a raw state (and the step, where the task observes time) to an action in
the action's units.

What the file computes is exactly what the project's controller
(:class:`~asap_dsl.backends.rl.sb3.PolicyController` inside :mod:`asap_dsl.rollout`) does with a
raw state, stage by stage:

1. the environment's observation: the state clipped into the state-space box, as float32; with
   ``observe state, time``, the steps left over the deadline, ``clip((deadline - step) /
   deadline, 0, hi)`` (the evaluation's episodes last the deadline);
2. the run's observation scaling, ``(s - centre) / half_width`` (:class:`~.sb3.Scaling`);
3. the actor network: its hidden layers and their activation, its output layer; SAC's
   deterministic action is the tanh of its mean, TD3's and DDPG's actor ends in tanh, PPO's and
   A2C's deterministic action is the mean;
4. what ``predict`` does with it in the model's action space (stable-baselines3 and sbx alike): a
   squashed output mapped from [-1, 1] onto that space, a Gaussian mean clipped into it;
5. the run's action scaling: the action times the kept model's gain (``action_gain``, 1 unless the
   policy search chose another), clipped to [-1, 1] and mapped onto the action bounds, then the clip
   to the bounds that the environment applies.

The network is read into plain arrays (:class:`Network`) from either engine — torch modules for
sb3, the flax parameters for sbx — so one builder per format serves both. Every computation is in
float32, as the policy's own. Metadata: the run's model sha256 and spec hash, the spec's state
and action names, the action bounds, the inputs' meaning (``metadata_props`` in ONNX;
``asap.json`` among a TorchScript file's extra files).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

from asap_dsl.env import float32_bounds
from asap_dsl.runfiles import RunError, atomic_write, shown

__all__ = ["FORMATS", "Network", "PolicyFunction", "export_run", "policy_function", "to_onnx", "to_torchscript"]

FORMATS = {"onnx": ".onnx", "torchscript": ".pt"}
#: The hidden layers' activations an exported file computes (the names of :mod:`.hyper`'s
#: ``activation_fn``, with each library's default parameters; ``gelu_tanh`` is flax's default gelu).
ACTIVATIONS = ("relu", "tanh", "elu", "leaky_relu", "gelu", "gelu_tanh", "silu", "sigmoid", "identity")
OPSET = 17  # onnxruntime reads it since 1.13 (2022); nothing newer is needed for an MLP
META_FILE = "asap.json"  # the TorchScript file's metadata, as torch.jit.save's extra file


@dataclass
class Network:
    """The actor as plain arrays: ``x -> act(x @ W_i + b_i)`` for the hidden layers, then the
    output layer (``tanh`` of it when ``squash``)."""

    weights: list[np.ndarray]      # [in, out], float32
    biases: list[np.ndarray]
    activation: str                # of the hidden layers: one of ACTIVATIONS
    squash: bool                   # tanh on the output (SAC's mean, TD3's and DDPG's actor)


@dataclass
class PolicyFunction:
    """Everything between a raw state and the controller's action (the module docstring's stages)."""

    net: Network
    obs_low: np.ndarray            # [n] float32: the state-space box of the observation
    obs_high: np.ndarray
    centre: np.ndarray             # [n] the observation scaling (zeros and ones without it)
    half: np.ndarray
    deadline: Optional[int]        # None: time is not observed
    time_high: float               # the largest time entry the environment observes
    squashed: bool                 # predict maps [-1, 1] onto the model's action space, else clips into it
    model_low: np.ndarray          # [m] the model's action space (the policy's [-1, 1] with action scaling)
    model_high: np.ndarray
    scale_low: Optional[np.ndarray]  # the action scaling's bounds (None: none)
    scale_high: Optional[np.ndarray]
    action_low: np.ndarray         # [m] the system's action bounds
    action_high: np.ndarray
    metadata: dict = field(default_factory=dict)
    gain: float = 1.0              # the action scaling's gain (:class:`~.sb3.Scaling`)

    @property
    def n_state(self) -> int:
        return int(self.obs_low.size)

    @property
    def n_action(self) -> int:
        return int(self.action_low.size)


# ------------------------------------------------------------------------------ reading a network
def _torch_activation(layer) -> Optional[str]:
    """The name of a torch activation module with its library default parameters, else None."""
    import torch.nn as tnn

    simple = {tnn.ReLU: "relu", tnn.Tanh: "tanh", tnn.SiLU: "silu", tnn.Sigmoid: "sigmoid"}
    if type(layer) in simple:
        return simple[type(layer)]
    if isinstance(layer, tnn.ELU) and layer.alpha == 1.0:
        return "elu"
    if isinstance(layer, tnn.LeakyReLU) and layer.negative_slope == 0.01:
        return "leaky_relu"
    if isinstance(layer, tnn.GELU):
        return "gelu" if layer.approximate == "none" else "gelu_tanh"
    return None


def _sb3_network(model, algo: str) -> Network:
    import torch.nn as tnn

    policy = model.policy
    if getattr(policy, "use_sde", False):
        raise RunError("cannot export a policy trained with gSDE (use_sde): its deterministic action is not "
                       "exported yet")
    if algo == "sac":
        extractor, layers = policy.actor.features_extractor, list(policy.actor.latent_pi) + [policy.actor.mu]
    elif algo in ("td3", "ddpg"):
        extractor, layers = policy.actor.features_extractor, list(policy.actor.mu)
    else:
        extractor = policy.pi_features_extractor
        layers = list(policy.mlp_extractor.policy_net) + [policy.action_net]
    if not isinstance(getattr(extractor, "flatten", None), tnn.Flatten):
        raise RunError(f"cannot export a policy with the features extractor {type(extractor).__name__}")
    squash = algo == "sac"
    if algo in ("td3", "ddpg") and layers and isinstance(layers[-1], tnn.Tanh):
        layers, squash = layers[:-1], True
    weights, biases, acts = [], [], set()
    for layer in layers:
        if isinstance(layer, tnn.Linear):
            weights.append(layer.weight.detach().cpu().numpy().T.astype(np.float32))
            biases.append(layer.bias.detach().cpu().numpy().astype(np.float32))
        elif _torch_activation(layer) is not None:
            acts.add(_torch_activation(layer))
        else:
            raise RunError(f"cannot export a policy with a {type(layer).__name__} layer")
    return Network(weights, biases, _one_activation(acts), squash)


def _sbx_activation(fn) -> str:
    """The activation's name: by its values on a few points (a model loaded from its zip holds an
    unpickled copy of the function, without a name)."""
    import jax.numpy as jnp
    from scipy.special import erf

    x = np.array([-2.5, -0.7, -0.1, 0.0, 0.4, 1.3, 3.0])
    refs = {"relu": np.maximum(x, 0.0), "tanh": np.tanh(x), "elu": np.where(x > 0, x, np.expm1(x)),
            "leaky_relu": np.where(x > 0, x, 0.01 * x), "sigmoid": 1 / (1 + np.exp(-x)), "silu": x / (1 + np.exp(-x)),
            "gelu": 0.5 * x * (1 + erf(x / np.sqrt(2))),
            "gelu_tanh": 0.5 * x * (1 + np.tanh(np.sqrt(2 / np.pi) * (x + 0.044715 * x ** 3)))}
    try:
        values = np.asarray(fn(jnp.asarray(x, dtype=jnp.float32)), dtype=np.float64)
    except Exception:  # noqa: BLE001 — not a plain elementwise function: refused below
        values = None
    for name, ref in refs.items():
        if values is not None and values.shape == x.shape and np.allclose(values, ref, rtol=1e-5, atol=1e-6):
            return name
    raise RunError(f"cannot export a policy whose activation is {getattr(fn, '__name__', None) or type(fn).__name__} "
                   f"(exported: {', '.join(ACTIVATIONS[:-1])})")


def _sbx_network(model, algo: str) -> Network:
    policy = model.policy
    actor = type(policy.actor).__name__
    if actor not in ("SquashedGaussianActor", "Actor") or getattr(policy.actor, "features_extractor", None):
        raise RunError(f"cannot export the sbx actor {actor} (only its MLP actors, without a features extractor)")
    params = policy.actor_state.params["params"]
    dense = sorted((k for k in params if k.startswith("Dense_")), key=lambda k: int(k.split("_")[1]))
    hidden = len(policy.actor.net_arch)
    layers = dense[: hidden + 1]  # SAC's next Dense is the log std, not part of the mean
    weights = [np.asarray(params[k]["kernel"], dtype=np.float32) for k in layers]
    biases = [np.asarray(params[k]["bias"], dtype=np.float32) for k in layers]
    act = _sbx_activation(policy.actor.activation_fn) if hidden else "identity"
    return Network(weights, biases, act, algo in ("sac", "td3", "ddpg"))


def _one_activation(found: set) -> str:
    if len(found) > 1:
        raise RunError(f"cannot export a policy mixing activations ({', '.join(sorted(found))})")
    return found.pop() if found else "identity"


def actor_network(model, engine: str, algo: str) -> Network:
    """The deterministic actor of a model of ``engine`` (``sb3`` or ``sbx``) as a :class:`Network`."""
    net = _sb3_network(model, algo) if engine == "sb3" else _sbx_network(model, algo)
    if algo in ("ppo", "a2c") and model.policy.squash_output:
        raise RunError(f"cannot export a {algo} policy with squash_output")
    for w, b in zip(net.weights, net.biases):
        if w.ndim != 2 or b.shape != (w.shape[1],):
            raise RunError(f"cannot export the policy: a layer of shape {w.shape} with a bias of {b.shape}")
    return net


def policy_function(loaded) -> PolicyFunction:
    """The :class:`PolicyFunction` of a run opened by :func:`~.evaluation.load_run`."""
    cfg, prog, model, scaling = loaded.config, loaded.program, loaded.model, loaded.scaling
    system, task = prog.system, prog.task(cfg.task).model
    net = actor_network(model, cfg.engine, cfg.algo)
    observe_time = "time" in task.observe
    n = system.n_state
    low, high = float32_bounds(system.state_low), float32_bounds(system.state_high)
    space = model.action_space
    meta = {
        "format": "asap-dsl policy 1",
        "run": str(loaded.run.path),
        "model_sha256": (loaded.manifest.get("model") or {}).get("sha256", ""),
        "spec_hash": loaded.manifest["spec_hash"],
        "spec_file": loaded.manifest.get("spec_file", ""),
        "system": system.name,
        "task": cfg.task,
        "algo": cfg.algo,
        "engine": cfg.engine,
        "state_names": list(system.state_names),
        "action_names": [a.name for a in system.actions],
        "action_low": [float(v) for v in system.action_low],
        "action_high": [float(v) for v in system.action_high],
        "observe_time": observe_time,
        "deadline": int(task.deadline),
        "dt": float(system.dt),
        "inputs": ["state", "step"] if observe_time else ["state"],
        "input_meaning": {"state": f"float32 [batch, {n}], the raw state in the spec's units ("
                                   + ", ".join(system.state_names) + ")",
                          **({"step": "float32 [batch], steps since the episode began (0 at its start); "
                                      f"the policy observes (deadline - step) / deadline with deadline "
                                      f"{int(task.deadline)}"} if observe_time else {})},
        "output": f"action: float32 [batch, {system.n_action}] in the action's units, within the bounds",
        "action_gain": float(scaling.gain),
    }
    if tuple(net.weights[0].shape[:1]) != (n + int(observe_time),) or net.weights[-1].shape[1] != system.n_action:
        raise RunError(f"{loaded.model_file}: the policy's layers do not fit the task's {n} states and "
                       f"{system.n_action} actions")
    return PolicyFunction(
        net=net, obs_low=low, obs_high=high,
        centre=np.asarray(scaling.obs_centre, np.float32), half=np.asarray(scaling.obs_half, np.float32),
        deadline=int(task.deadline) if observe_time else None,
        time_high=float(np.float32(max(1.0, task.episode[1] / task.deadline))),
        squashed=bool(model.policy.squash_output),
        model_low=np.asarray(space.low, np.float32), model_high=np.asarray(space.high, np.float32),
        scale_low=None if scaling.act_low is None else np.asarray(scaling.act_low, np.float64),
        scale_high=None if scaling.act_high is None else np.asarray(scaling.act_high, np.float64),
        action_low=np.asarray(system.action_low, np.float64), action_high=np.asarray(system.action_high, np.float64),
        metadata=meta, gain=float(scaling.gain))


# ------------------------------------------------------------------------------------ TorchScript
def to_torchscript(fn: PolicyFunction) -> bytes:
    """The policy as a TorchScript file (``torch.jit.load``; metadata in its ``asap.json``)."""
    import io

    import torch

    from .export_torch import build_module

    module = torch.jit.script(build_module(fn))
    buf = io.BytesIO()
    torch.jit.save(module, buf, _extra_files={META_FILE: json.dumps(fn.metadata, indent=1)})
    return buf.getvalue()


# ------------------------------------------------------------------------------------------- ONNX
def to_onnx(fn: PolicyFunction) -> bytes:
    """The policy as an ONNX model (opset 17) with the metadata in its ``metadata_props``."""
    from onnx import TensorProto, checker, helper, numpy_helper

    nodes, inits = [], []
    count = [0]

    def const(name: str, value, dtype=np.float32) -> str:
        inits.append(numpy_helper.from_array(np.asarray(value, dtype=dtype), name))
        return name

    def op(kind: str, *inputs: str, **attrs) -> str:
        count[0] += 1
        out = f"{kind.lower()}_{count[0]}"
        nodes.append(helper.make_node(kind, list(inputs), [out], **attrs))
        return out

    def clip(x: str, lo: str, hi: str) -> str:  # per entry (Clip takes scalars only)
        return op("Max", op("Min", x, hi), lo)

    def unscale(x: str, lo: np.ndarray, hi: np.ndarray, tag: str, dtype=np.float32) -> str:
        # low + (clip(x, -1, 1) + 1) * 0.5 * (high - low), in the order the controller computes it
        u = clip(x, const(f"{tag}_minus_one", -1.0, dtype), const(f"{tag}_one", 1.0, dtype))
        u = op("Mul", op("Add", u, const(f"{tag}_one_b", 1.0, dtype)), const(f"{tag}_half", 0.5, dtype))
        lo, hi = np.asarray(lo, dtype), np.asarray(hi, dtype)
        return op("Add", const(f"{tag}_low", lo, dtype), op("Mul", u, const(f"{tag}_width", hi - lo, dtype)))

    def activation(x: str, name: str) -> str:
        if name in ("relu", "tanh", "elu", "sigmoid"):
            return op({"relu": "Relu", "tanh": "Tanh", "elu": "Elu", "sigmoid": "Sigmoid"}[name], x)
        if name == "leaky_relu":
            return op("LeakyRelu", x, alpha=0.01)
        if name == "silu":
            return op("Mul", x, op("Sigmoid", x))
        if name == "gelu":   # 0.5 x (1 + erf(x / sqrt 2)); Gelu is an operator only from opset 20
            e = op("Erf", op("Mul", x, const(f"c{count[0]}_r2", 1 / np.sqrt(2))))
            return op("Mul", op("Mul", x, const(f"c{count[0]}_half", 0.5)), op("Add", e, const(f"c{count[0]}_one", 1.0)))
        if name == "gelu_tanh":  # 0.5 x (1 + tanh(sqrt(2/pi) (x + 0.044715 x^3)))
            cube = op("Mul", op("Mul", x, x), x)
            inner = op("Add", x, op("Mul", cube, const(f"c{count[0]}_k", 0.044715)))
            t = op("Tanh", op("Mul", inner, const(f"c{count[0]}_s", np.sqrt(2 / np.pi))))
            return op("Mul", op("Mul", x, const(f"c{count[0]}_half", 0.5)), op("Add", t, const(f"c{count[0]}_one", 1.0)))
        return x  # identity

    n, m = fn.n_state, fn.n_action
    x = clip("state", const("obs_low", fn.obs_low), const("obs_high", fn.obs_high))
    x = op("Div", op("Sub", x, const("obs_centre", fn.centre)), const("obs_half", fn.half))
    inputs = [helper.make_tensor_value_info("state", TensorProto.FLOAT, ["batch", n])]
    if fn.deadline is not None:
        inputs.append(helper.make_tensor_value_info("step", TensorProto.FLOAT, ["batch"]))
        left = op("Div", op("Sub", const("deadline", float(fn.deadline)), "step"), const("deadline_b", float(fn.deadline)))
        left = clip(left, const("time_low", 0.0), const("time_high", fn.time_high))
        x = op("Concat", x, op("Unsqueeze", left, const_int64(inits, "axis_1", [1])), axis=1)
    net = fn.net
    for i, (w, b) in enumerate(zip(net.weights, net.biases)):
        x = op("Add", op("MatMul", x, const(f"W{i}", w)), const(f"b{i}", b))
        if i < len(net.weights) - 1:
            x = activation(x, net.activation)
    if net.squash:
        x = op("Tanh", x)
    if fn.squashed:
        x = unscale(x, fn.model_low, fn.model_high, "model")
    else:
        x = clip(x, const("model_low", fn.model_low), const("model_high", fn.model_high))
    # The action scaling in double, as the controller computes it: near a bound of a wide action
    # range, float32's rounding of low + (u + 1) * width / 2 would cost digits the policy has.
    x = op("Cast", x, to=TensorProto.DOUBLE)
    if fn.scale_low is not None:
        if fn.gain != 1.0:
            x = op("Mul", x, const("action_gain", fn.gain, np.float64))
        x = unscale(x, fn.scale_low, fn.scale_high, "scale", np.float64)
    x = clip(x, const("action_low", fn.action_low, np.float64), const("action_high", fn.action_high, np.float64))
    nodes.append(helper.make_node("Cast", [x], ["action"], to=TensorProto.FLOAT))
    graph = helper.make_graph(nodes, "asap_policy", inputs,
                              [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", m])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="asap-dsl")
    model.ir_version = 8  # what opset 17 needs; older runtimes refuse newer IR versions
    model.doc_string = (f"{fn.metadata.get('algo', '')} policy of task {fn.metadata.get('task', '')}: "
                        "state (and step) -> action in the action's units")
    helper.set_model_props(model, {k: v if isinstance(v, str) else json.dumps(v) for k, v in fn.metadata.items()})
    checker.check_model(model)
    return model.SerializeToString()


def const_int64(inits: list, name: str, value) -> str:
    from onnx import numpy_helper

    inits.append(numpy_helper.from_array(np.asarray(value, dtype=np.int64), name))
    return name


# ------------------------------------------------------------------------------------ the command
def default_path(run: Union[str, Path], fmt: str) -> Path:
    """``RUN/policy.onnx`` or ``RUN/policy.pt``."""
    return Path(run) / f"policy{FORMATS[fmt]}"


def _needs(module: str, package: str) -> None:
    import importlib.util

    if importlib.util.find_spec(module) is None:
        raise RunError(f"exporting to this format needs the {package} package: pip install {package}")


def _check_target(target: Path, run: Path) -> None:
    """Refuse a destination whose replacement loses something: a device or other special file, or
    one of the run's own files (its model, manifest, checkpoints) rather than an earlier export."""
    if not target.exists():
        return
    if not target.is_file():
        raise RunError(f"{shown(target)}: not a regular file (a device, pipe or socket); give a file path for --out")
    if target.resolve().parent == run.resolve() and target.suffix not in FORMATS.values():
        raise RunError(f"{shown(target)}: one of the run's own files; exporting there would destroy it "
                       f"(give a path ending in {' or '.join(FORMATS.values())})")


def export_run(run: Union[str, Path], fmt: str = "onnx", out: Union[str, Path, None] = None,
               spec: Union[str, Path, None] = None) -> tuple[Path, PolicyFunction]:
    """Export a run's best model (the one ``asapc eval`` evaluates) as ``fmt`` (``onnx`` or
    ``torchscript``) to ``out`` (default :func:`default_path`), written atomically.

    :raises asap_dsl.runs.RunError: the run cannot be read or exported, or the file written (one sentence).
    :raises ValueError: an unknown format.
    """
    from .evaluation import load_run

    if fmt not in FORMATS:
        raise ValueError(f"the format is onnx or torchscript; got {fmt!r}")
    if fmt == "onnx":
        _needs("onnx", "onnx")  # onnxruntime only runs the file: not needed to write it
    else:
        _needs("torch", "torch")
    target = Path(out).expanduser() if out else default_path(run, fmt)
    if target.is_dir():
        target = target / f"policy{FORMATS[fmt]}"
    _check_target(target, Path(run))
    fn = policy_function(load_run(run, spec))
    data = to_onnx(fn) if fmt == "onnx" else to_torchscript(fn)
    atomic_write(target, data)
    return target, fn


def read_metadata(path: Union[str, Path]) -> dict[str, Any]:
    """The metadata of an exported file (either format), as :func:`policy_function` wrote it."""
    path = Path(path)
    head = path.read_bytes()[:2]
    if head == b"PK":  # TorchScript files are zip archives
        import torch

        extra = {META_FILE: ""}
        torch.jit.load(str(path), _extra_files=extra)
        return json.loads(extra[META_FILE])
    import onnx

    props = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    out = {}
    for k, v in props.items():
        try:
            out[k] = json.loads(v) if v[:1] in "[{" or v in ("true", "false") or v.lstrip("-").isdigit() else v
        except ValueError:
            out[k] = v
    return out


def describe(path: Path, fn: PolicyFunction, fmt: str) -> str:
    """What ``asapc export`` prints: the file and its signature."""
    meta = fn.metadata
    ins = ", ".join(meta["inputs"])
    return (f"wrote {shown(path)} ({fmt}): ({ins}) -> action [{', '.join(meta['action_names'])}]; "
            f"{meta['algo']} on {meta['engine']}, task {meta['task']}, model {meta['model_sha256'][:12]}")
