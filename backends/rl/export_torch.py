"""The exported policy as a torch module (:mod:`.export`'s stages, the same float32 operations in
the same order as its ONNX graph); scripted by :func:`.export.to_torchscript`. Imports torch."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

__all__ = ["build_module"]


def _t(a) -> torch.Tensor:
    return torch.from_numpy(np.array(a, dtype=np.float32))  # a copy: writable, as torch wants


_ACTIVATIONS = {"relu": nn.ReLU, "tanh": nn.Tanh, "elu": nn.ELU, "leaky_relu": nn.LeakyReLU, "silu": nn.SiLU,
                "sigmoid": nn.Sigmoid, "gelu": nn.GELU, "gelu_tanh": lambda: nn.GELU(approximate="tanh")}


class Policy(nn.Module):
    """``forward(state [B, n]) -> action [B, m]`` in the action's units."""

    def __init__(self, fn):
        super().__init__()
        net = fn.net
        layers: list[nn.Module] = []
        for i, (w, b) in enumerate(zip(net.weights, net.biases)):
            lin = nn.Linear(w.shape[0], w.shape[1])
            with torch.no_grad():
                lin.weight.copy_(_t(w.T))
                lin.bias.copy_(_t(b))
            layers.append(lin)
            if i < len(net.weights) - 1 and net.activation != "identity":
                layers.append(_ACTIVATIONS[net.activation]())
        if net.squash:
            layers.append(nn.Tanh())
        self.net = nn.Sequential(*layers)
        self.squashed = bool(fn.squashed)
        self.scaled = fn.scale_low is not None
        self.gain = float(fn.gain)
        for name, value in (("obs_low", fn.obs_low), ("obs_high", fn.obs_high), ("centre", fn.centre),
                            ("half_width", fn.half), ("model_low", fn.model_low), ("model_high", fn.model_high)):
            self.register_buffer(name, _t(value))
        # the action scaling in double, as the controller computes it (see export.to_onnx)
        for name, value in (("scale_low", fn.scale_low if self.scaled else fn.action_low),
                            ("scale_high", fn.scale_high if self.scaled else fn.action_high),
                            ("action_low", fn.action_low), ("action_high", fn.action_high)):
            self.register_buffer(name, torch.as_tensor(np.asarray(value, dtype=np.float64)))

    def observe(self, state: torch.Tensor) -> torch.Tensor:
        x = torch.maximum(torch.minimum(state.to(torch.float32), self.obs_high), self.obs_low)
        return (x - self.centre) / self.half_width

    def act(self, x: torch.Tensor) -> torch.Tensor:
        y = self.net(x)
        if self.squashed:  # predict maps [-1, 1] onto the model's action space
            y = self.model_low + (torch.clamp(y, -1.0, 1.0) + 1.0) * 0.5 * (self.model_high - self.model_low)
        else:              # a Gaussian mean clipped into it
            y = torch.maximum(torch.minimum(y, self.model_high), self.model_low)
        a = y.to(torch.float64)
        if self.scaled:
            a = self.scale_low + (torch.clamp(self.gain * a, -1.0, 1.0) + 1.0) * 0.5 * (self.scale_high - self.scale_low)
        return torch.maximum(torch.minimum(a, self.action_high), self.action_low).to(torch.float32)

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        return self.act(self.observe(state))


class TimedPolicy(Policy):
    """``forward(state [B, n], step [B]) -> action [B, m]``: the task observes time."""

    def __init__(self, fn):
        super().__init__(fn)
        self.deadline = float(fn.deadline)
        self.time_high = float(fn.time_high)

    def forward(self, state: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        left = (self.deadline - step.to(torch.float32)) / self.deadline
        left = torch.clamp(left, 0.0, self.time_high)
        return self.act(torch.cat([self.observe(state), left.unsqueeze(1)], dim=1))


def build_module(fn) -> nn.Module:
    """The module of a :class:`~.export.PolicyFunction`, in evaluation mode."""
    module = (TimedPolicy(fn) if fn.deadline is not None else Policy(fn)).eval()
    module.requires_grad_(False)  # a deployed function: its outputs carry no autograd graph
    return module
