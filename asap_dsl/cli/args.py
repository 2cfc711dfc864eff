"""What every ``asapc`` command shares: its failures, the argparse types, the shared flags.

A command reports a failure by raising a :class:`CliError` (``asapc: error: <sentence>``, with
its exit status); :func:`asap_dsl.cli.main` is the one place that prints it. The flags that
several commands take (``--task``, ``--seed``, ``--episodes``, ``--workers``/``--force-workers``,
``--format``) are added here, so they read and check the same everywhere.
"""

from __future__ import annotations

import argparse
from typing import Callable, Optional

from ..limits import LIMITS, available_cores

__all__ = ["CliError", "EMPTY_TASK", "InputError", "UsageError", "add_episodes", "add_format", "add_seed",
           "add_task", "add_workers", "check_task", "episodes_int", "names_list", "natural_int", "planner_samples",
           "positive_amount",
           "path_arg", "positive_int", "share_float", "seed_int", "steps_int", "tolerances_list", "workers"]


# ------------------------------------------------------------------------------------ failures
class CliError(Exception):
    """A failure told in one sentence, ``asapc: error: <message>``, and its exit status."""

    code = 1

    def __init__(self, message: str):
        super().__init__(message)
        self.message = message


class InputError(CliError):
    """A problem with what the user gave: a spec without tasks, a damaged or foreign run
    directory, a run that cannot go on (exit 1)."""

    code = 1


class UsageError(CliError):
    """A flag or argument that is misused, or names something the spec does not have (exit 2,
    the status argparse gives its own usage errors)."""

    code = 2


EMPTY_TASK = "--task needs a task name (leave it out for every task, or the only one)"


# ------------------------------------------------------------------------------- argparse types
def path_arg(text: str) -> str:
    """argparse type: a file or directory name; an empty one would mean the current directory
    (`--out ""` wrote a sweep's lock and runs there)."""
    if text == "":
        raise argparse.ArgumentTypeError("expected a path, got an empty text")
    return text


def _whole(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None


def positive_int(text: str) -> int:
    """argparse type: a whole number of at least 1, in plain words otherwise."""
    value = _whole(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {value}")
    return value


def megabytes(text: str) -> int:
    """argparse type: a size in MB, from 1 up to a terabyte (larger is no file a spec could be)."""
    value = positive_int(text)
    if value > 1 << 20:
        raise argparse.ArgumentTypeError(f"expected at most {1 << 20:,} MB (a terabyte), got {value:,}")
    return value


def natural_int(text: str) -> int:
    """argparse type: a whole number of at least 0."""
    value = _whole(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected 0 or more, got {value}")
    return value


def share_float(text: str) -> float:
    """argparse type: a share between 0 and 1."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number between 0 and 1, got '{text}'") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number between 0 and 1, got {text}")
    return value


def weight_float(text: str) -> float:
    """argparse type: a finite number of 0 or more."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of 0 or more, got '{text}'") from None
    if not 0.0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number of 0 or more, got {text}")
    return value


def seed_int(text: str) -> int:
    """argparse type: a seed, 0 .. 2^32 - 1."""
    value = _whole(text)
    if not 0 <= value < 2**32:
        raise argparse.ArgumentTypeError(f"a seed is between 0 and 2^32 - 1, got {value}")
    return value


def planner_samples(text: str) -> int:
    """argparse type: the planner's candidates per iteration, 8 .. 65,536 (one batch of the simulator)."""
    value = _whole(text)
    if not 8 <= value <= 65536:
        raise argparse.ArgumentTypeError(f"the planner needs 8 to 65,536 samples per iteration, got {value:,}")
    return value


def episodes_int(text: str) -> int:
    """argparse type: a number of initial states, 1 .. ``LIMITS.episodes``."""
    value = positive_int(text)
    if value > LIMITS.episodes:
        raise argparse.ArgumentTypeError(f"at most {LIMITS.episodes:,} initial states, got {value:,}")
    return value


def steps_int(text: str) -> int:
    """argparse type: whole steps, also written as 2e5 or 200_000."""
    try:
        value = float(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of steps, got '{text}'") from None
    if not value.is_integer() or value < 1 or value > 1e12:
        raise argparse.ArgumentTypeError(f"expected a whole number of steps between 1 and 1e12, got '{text}'")
    return int(value)


def positive_amount(unit: str, limit: float = 1e6) -> Callable[[str], float]:
    """argparse type: a positive, finite number of ``unit`` (minutes, seconds), below ``limit``."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {unit}, got '{text}'") from None
        if not 0 < value < limit:
            raise argparse.ArgumentTypeError(f"expected a positive number of {unit} below {limit:g}, got '{text}'")
        return value

    parse.__name__ = unit  # argparse names the type in its messages
    return parse


def tolerances_list(text: str) -> list[int]:
    """argparse type: tolerances in steps, comma-separated (``30,25,15``)."""
    out = []
    for part in text.replace(" ", "").split(","):
        if not part:
            continue
        try:
            v = int(part)
        except ValueError:
            raise argparse.ArgumentTypeError(f"tolerances are whole numbers of steps separated by commas, got '{text}'") from None
        if v < 1:
            raise argparse.ArgumentTypeError(f"a tolerance is at least 1 step, got {v}")
        out.append(v)
    if not out:
        raise argparse.ArgumentTypeError("give at least one tolerance, such as 30,25,15")
    return out


def names_list(text: str) -> list[str]:
    """argparse type: names, comma-separated (``asap,rho``); at least one."""
    items = [x.strip() for x in text.split(",") if x.strip()]
    if not items:
        raise argparse.ArgumentTypeError("give at least one name, comma-separated")
    return items


# -------------------------------------------------------------------------------- shared flags
def add_task(p: argparse.ArgumentParser, help: str) -> None:
    """``--task NAME``; :func:`check_task` checks it against the spec."""
    p.add_argument("--task", default=None, help=help)


def check_task(name: Optional[str], prog=None) -> None:
    """Refuse an empty ``--task`` and, given the program, a task it does not have (the one wording
    of :meth:`asap_dsl.Program.task`, with its suggestion)."""
    if name == "":
        raise UsageError(EMPTY_TASK)
    if name is not None and prog is not None:
        try:
            prog.task(name)
        except KeyError as err:
            raise UsageError(str(err.args[0])) from None


def add_seed(p: argparse.ArgumentParser, default: Optional[int], help: str) -> None:
    """``--seed S`` (0 .. 2^32 - 1)."""
    p.add_argument("--seed", type=seed_int, default=default, help=help)


def add_episodes(p: argparse.ArgumentParser, help: str) -> None:
    """``--episodes N``: initial states, 1 .. ``LIMITS.episodes`` (default 1000)."""
    p.add_argument("--episodes", type=episodes_int, default=1000, help=help)


def add_workers(p: argparse.ArgumentParser, what: str) -> None:
    """``--workers K`` and ``--force-workers``; :func:`workers` resolves and checks them."""
    p.add_argument("--workers", type=positive_int, default=None,
                   help=f"{what} (default: one per core; at most the cores)")
    p.add_argument("--force-workers", action="store_true", help="allow more workers than cores")


def add_learner_phases(p: argparse.ArgumentParser) -> None:
    """``--imitation W`` and ``--search-iterations N``: the default preset's phases beside and after
    the learner, for a run (``asapc train``) or every run of a sweep (``asapc compare``)."""
    p.add_argument("--imitation", type=weight_float, metavar="W",
                   help="SAC's actor also imitates the oracle's minimum-time paths with this weight (sbx engine, "
                        "known dynamics): those of the preset's 2,500 initial states (or of --demonstrations N) that "
                        "1,440 CPU seconds of the oracle solve (12 minutes on 2 cores), all in the replay buffer from "
                        "the start (default: the preset's, 0.1 where it can; 0: none)")
    p.add_argument("--search-iterations", type=natural_int, metavar="N",
                   help="after the learner, evolution strategies on the best actor for N iterations, the model kept "
                        "only if it beats the learner's on validation (SAC, TD3, DDPG on sbx; default: the preset's, "
                        "1,000 on known dynamics; 0: none)")


def workers(args: argparse.Namespace) -> int:
    """The processes asked for, one per core by default. More than the cores only slow every one
    of them down: refused unless ``--force-workers``."""
    cores = available_cores()
    n = args.workers if args.workers is not None else cores
    if n > cores and not args.force_workers:
        raise UsageError(f"--workers {n} is more than the {cores} cores available; pass --force-workers to insist")
    return n


def add_format(p: argparse.ArgumentParser) -> None:
    """``--format text|json`` (text by default)."""
    p.add_argument("--format", choices=("text", "json"), default="text", help="output format (default text)")
