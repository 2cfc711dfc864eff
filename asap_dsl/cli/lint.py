"""``asapc lint FILE... [--strict] [--deep] [--format json]``: every problem of every file, at once.

The checks are :mod:`asap_dsl.checker` and :mod:`asap_dsl.lint` (W208 with ``--deep``,
:func:`asap_dsl.lint.deadline_checks`); this module reads the files and prints the report.
Exit status: 0 no error (warnings fail only with ``--strict``), 1 an error in some file.
"""

from __future__ import annotations

import argparse
import json
from typing import Optional

from ..diagnostics import SHOWN, Diagnostic, SpecError, format_report, printable
from ..formatting import plural
from ..lint import deadline_checks
from ..program import Program, analyse, read_source
from .args import add_format, natural_int, path_arg, positive_amount, positive_int

__all__ = ["fill_lint_subparser", "lint_command"]


def fill_lint_subparser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("lint", help="check spec files and report every problem")
    p.add_argument("files", type=path_arg, nargs="+", metavar="FILE")
    add_format(p)
    p.add_argument("--strict", action="store_true", help="warnings fail too (exit 1)")
    p.add_argument("--deep", action="store_true", help="also sample initial states and check with the oracle "
                   "that the deadline is feasible (ode and map systems)")
    p.add_argument("--max-diagnostics", type=natural_int, default=SHOWN, metavar="N",
                   help=f"print the first N diagnostics in full and count the rest (default {SHOWN}; 0: all)")
    p.add_argument("--samples", type=positive_int, default=16, help="initial states sampled by --deep (default 16)")
    p.add_argument("--deep-seconds", type=positive_amount("seconds"), default=60.0, metavar="SECONDS",
                   help="search time of --deep per task, shared by its samples (default 60)")
    p.set_defaults(func=lint_command)
    return p


def _lint_file(path: str) -> tuple[list[Diagnostic], Optional[str], Optional[Program]]:
    """The diagnostics of one file, its text (None if unreadable) and its program if it compiles."""
    try:
        text = read_source(path)
    except SpecError as err:
        return err.diagnostics, err.source, None
    try:
        model, diagnostics = analyse(text, path)
    except SpecError as err:  # syntax errors
        return err.diagnostics, text, None
    prog = Program(model, [d for d in diagnostics if not d.is_error]) if model is not None else None
    return diagnostics, text, prog


def lint_command(args: argparse.Namespace) -> int:
    """Check every file and print the diagnostics (text or JSON); 1 when any is an error."""
    all_diags: list[Diagnostic] = []
    sources: dict[str, Optional[str]] = {}
    skipped: list[dict] = []  # what --deep could not check, and why
    for path in args.files:
        diags, source, prog = _lint_file(path)
        if args.deep and prog is not None:
            deep, why = deadline_checks(prog, samples=args.samples, seconds=args.deep_seconds)
            diags = diags + deep
            skipped += [{"file": path, "task": task, "reason": reason} for task, reason in why]
        all_diags += diags
        sources[path] = source
    errors = sum(d.is_error for d in all_diags)
    warnings = len(all_diags) - errors
    if args.format == "json":
        print(json.dumps({"files": args.files, "errors": errors, "warnings": warnings,
                          "diagnostics": [d.as_dict() for d in all_diags],
                          **({"deep_skipped": skipped} if args.deep else {})}, indent=2))
    else:
        if all_diags:
            print(format_report(all_diags, sources, args.max_diagnostics))
        for s in skipped:
            print(printable(f"{s['file']}: --deep did not check task '{s['task']}': {s['reason']}"))
        print(f"{plural(len(args.files), 'file')} checked: {plural(errors, 'error')}, {plural(warnings, 'warning')}")
    return 1 if errors or (args.strict and warnings) else 0
