"""``asapc export RUN [--format onnx|torchscript] [--out FILE] [--spec FILE]``: a trained run's
deterministic policy as one file that maps a raw state (and the step, where the task observes
time) to an action in the action's units, the run's observation and action scaling folded in
(:mod:`asap_dsl.backends.rl.export`; docs/export.md shows how to call it from C++ and Python).

Exit status: 0 written, 1 a problem with the run directory or the file, 2 a bad flag.
"""

from __future__ import annotations

import argparse
import sys
from typing import Optional, TextIO

from .args import InputError, UsageError, path_arg

__all__ = ["export_command", "fill_export_subparser"]


def fill_export_subparser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("export", help="write a trained run's policy as ONNX or TorchScript (scaling included)")
    p.add_argument("run", type=path_arg, metavar="RUN", help="a run directory written by `asapc train`")
    p.add_argument("--format", choices=("onnx", "torchscript"), default="onnx",
                   help="onnx (onnxruntime, C++ or Python) or torchscript (torch.jit.load, LibTorch); default onnx")
    p.add_argument("--out", type=path_arg, metavar="FILE", default=None,
                   help="the file to write (default: RUN/policy.onnx or RUN/policy.pt)")
    p.add_argument("--spec", type=path_arg, help="check the run against this spec file (it must be the one the run was trained on)")
    p.set_defaults(func=export_command)
    return p


def export_command(args: argparse.Namespace, out: Optional[TextIO] = None) -> int:
    """Export the run's best model (the one ``asapc eval`` evaluates) and say what was written."""
    from asap_dsl.backends.rl.export import describe, export_run
    from asap_dsl.runs import RunError

    out = out or sys.stdout
    try:
        path, fn = export_run(args.run, args.format, args.out, spec=args.spec)
    except RunError as e:
        raise InputError(str(e)) from None
    except ValueError as e:
        raise UsageError(str(e)) from None
    out.write(describe(path, fn, args.format) + "\n")
    return 0
