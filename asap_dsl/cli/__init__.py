"""``asapc``: the command line. I/O lives here; everything it reports is computed elsewhere.

One module per command (:mod:`.lint`, :mod:`.show`, :mod:`.train`, :mod:`.eval`, :mod:`.export`,
:mod:`.tune`, :mod:`.oracle`, :mod:`.compare`), each with a ``fill_X_subparser`` that adds its flags and an ``X_command`` that
runs it; what they share (argparse types, ``--task``, ``--seed``, ``--workers``, the failures) is
:mod:`.args`. A command fails by raising; :func:`main` is the one place that turns an exception
into a sentence and an exit status:

0 success, 1 a problem in the user's spec or data, 2 a usage error (bad flags), 70 an internal
error (a bug of ours, reported in one line; ``ASAPC_DEBUG=1`` shows the trace), 130 interrupted.
"""

from __future__ import annotations

import os
import signal
import sys


def _terminated_early(signum, frame) -> None:  # before main(): nothing exists yet, so nothing to save
    os.write(2, b"interrupted\n")
    os._exit(130)


# As the program (`asapc`, `python -m asap_dsl.cli`), SIGTERM is handled from the first import on:
# what follows takes a second to load, and a SIGTERM then must not end it silently (143).
_PROGRAM = sys.argv[:1] == ["-m"] or os.path.basename(sys.argv[0] if sys.argv else "") == "asapc"
if _PROGRAM:
    for _sig, _default in ((signal.SIGTERM, signal.SIG_DFL), (signal.SIGINT, signal.default_int_handler)):
        if signal.getsignal(_sig) is _default:
            signal.signal(_sig, _terminated_early)

import argparse  # noqa: E402
from typing import NoReturn, Optional, Sequence  # noqa: E402

from .. import __version__
from ..diagnostics import SpecError, printable
from ..formatting import plural
from ..limits import LIMITS, available_cores
from .args import CliError, megabytes, positive_int
from .compare import fill_compare_subparser
from .eval import fill_eval_subparser
from .export import fill_export_subparser
from .lint import fill_lint_subparser
from .oracle import fill_oracle_subparser
from .show import fill_show_subparser, show_data
from .train import fill_train_subparser
from .tune import fill_tune_subparser

# available_cores and show_data: the library's, named here for scripts that used them from the CLI.
__all__ = ["available_cores", "build_parser", "exit_as_program", "main", "show_data"]


def build_parser() -> argparse.ArgumentParser:
    """``asapc``'s parser: the global limits, then one subparser per command."""
    p = argparse.ArgumentParser(prog="asapc", description="Check, compile and solve .asap specifications of "
                                "control tasks to fulfil as soon as possible.")
    p.add_argument("-V", "--version", action="version", version=f"asapc {__version__}")
    p.add_argument("--max-spec-size", type=megabytes, metavar="MB", default=None,
                   help="read spec files up to this size (default 10 MB)")
    p.add_argument("--max-deadline", type=positive_int, metavar="STEPS", default=None,
                   help=f"accept deadlines (episodes, windows, oracle horizons) up to this many steps "
                   f"(default {LIMITS.deadline_steps:,})")
    p.add_argument("--max-substeps", type=positive_int, metavar="N", default=None,
                   help=f"accept integrators with up to N substeps per step (default {LIMITS.substeps:,})")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for fill in (fill_lint_subparser, fill_show_subparser, fill_train_subparser, fill_eval_subparser,
                 fill_export_subparser, fill_tune_subparser, fill_compare_subparser, fill_oracle_subparser):
        fill(sub)
    return p


def _apply_limits(args: argparse.Namespace) -> None:
    """The global flags raise this process's limits (:data:`asap_dsl.limits.LIMITS`)."""
    if args.max_spec_size is not None:
        LIMITS.spec_bytes = args.max_spec_size * 1024 * 1024
    if args.max_deadline is not None:
        LIMITS.deadline_steps = args.max_deadline
    if args.max_substeps is not None:
        LIMITS.substeps = args.max_substeps


def _exit_status(err: BaseException) -> int:
    """Say what went wrong on standard error and give the exit status: the one path from a
    failure to what the user reads. A usage error (2) leaves through ``SystemExit``, as
    argparse's own do; a bug of ours is re-raised with ``ASAPC_DEBUG`` set."""
    if isinstance(err, SpecError):
        print(err.report(), file=sys.stderr)
        print(plural(len(err.errors), "error"), file=sys.stderr)
        return 1
    if isinstance(err, CliError):
        print(f"asapc: error: {printable(err.message)}", file=sys.stderr)  # paths may hold ESC bytes
        if err.code == 2:  # as argparse exits for a flag it rejects
            raise SystemExit(2)
        return err.code
    from ..sim import SimulatorError  # loaded by then if a simulator ran

    if isinstance(err, SimulatorError):  # the user's simulator code failed; the sentence names the spec line
        print(f"asapc: error: {printable(str(err))}", file=sys.stderr)
        return 1
    if isinstance(err, KeyboardInterrupt):
        print("interrupted", file=sys.stderr)
        return 130
    if isinstance(err, BrokenPipeError):  # the reader left (`asapc show ... | head`)
        return 0
    if isinstance(err, OSError) and err.filename is not None and err.strerror:
        # The system refused a path the user gave (a name too long, no space left, no permission).
        print(f"asapc: error: {printable(str(err.filename))}: {err.strerror.lower()}", file=sys.stderr)
        return 1
    if os.environ.get("ASAPC_DEBUG"):
        raise err
    print(f"asapc: internal error: {type(err).__name__}: {err} (set ASAPC_DEBUG=1 for the trace; please report it)",
          file=sys.stderr)
    return 70


def _terminated(signum, frame) -> None:
    raise KeyboardInterrupt  # SIGTERM ends a command as Ctrl-C does (exit 130), never silently (143)


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run ``asapc ARGV`` (``sys.argv[1:]`` by default) and return its exit status."""
    import threading

    main_thread = (threading.current_thread() is threading.main_thread()
                   and signal.getsignal(signal.SIGTERM) in (signal.SIG_DFL, _terminated_early))
    old = signal.signal(signal.SIGTERM, _terminated) if main_thread else None
    if signal.getsignal(signal.SIGINT) is _terminated_early:  # from here on, Ctrl-C unwinds (files are closed)
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        args = build_parser().parse_args(argv)
        _apply_limits(args)
        return int(args.func(args) or 0)
    except (Exception, KeyboardInterrupt) as err:
        return _exit_status(err)
    finally:
        if _PROGRAM and main_thread:
            # The command is over and its status decided. Python's finalization resets handlers to
            # the default, so a signal while torch and JAX tear down would end a finished command
            # as 143; ignored from here on, the status says what happened.
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        elif main_thread:
            signal.signal(signal.SIGTERM, old)


def exit_as_program(status: int) -> NoReturn:
    """End the process with ``status`` (``python -m asap_dsl.cli``'s last step).

    CPython remembers a KeyboardInterrupt that cut any string run by ``exec`` (a dataclass or a
    namedtuple being built by an import when SIGTERM arrived), even after :func:`main` caught it,
    and under ``-m`` then ends the process by SIGINT instead of with the status (-2, not 130;
    found by the random fault schedule on CI). Running a string resets that memory."""
    exec("")
    sys.exit(status)
