"""The command lines whose output must not change when the code is reorganised, and how to run one.

``python tests/golden.py`` records their outputs into tests/data/golden/; tests/test_golden.py
compares today's outputs with the recorded ones, byte for byte (timing fields aside).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
GOLDEN = ROOT / "tests" / "data" / "golden"

#: The specs and examples the outputs were recorded for (a file added since, such as
#: examples/mountain_car.asap, has tests of its own: recording it here would re-record).
FILES = ["examples/broken.asap", "examples/double_integrator.asap", "specs/attitude.asap", "specs/bicycle.asap",
         "specs/dc_motor.asap", "specs/swimmer.asap"]


def commands() -> list[list[str]]:
    """Every recorded command line: lint, show and oracle as JSON on every spec and example, and
    the README's text output of ``asapc lint examples/broken.asap``."""
    out = [["lint", "examples/broken.asap"]]
    for f in FILES:
        out.append(["lint", "--format", "json", f])
        out.append(["show", "--format", "json", f])
        out.append(["show", f])
        if "swimmer" not in f:  # a black box: `asapc oracle` plans through it (issue 17), by design no longer "none"
            out.append(["oracle", "--format", "json", "--episodes", "4", "--workers", "1", f])
    return out


def name(argv: list[str]) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", " ".join(a for a in argv if a != "--format")).strip("_") + ".txt"


_TIMING = re.compile(r'("seconds": )[0-9.eE+-]+')


def normalise(text: str) -> str:
    """The output without what measures time (an oracle's wall seconds)."""
    return _TIMING.sub(r"\g<1>0", text)


def run(argv: list[str]) -> str:
    """The exit code, standard output and standard error of ``asapc ARGV`` run from the repository root."""
    from asap_dsl import cli

    out, err = io.StringIO(), io.StringIO()
    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = cli.main(list(argv))
            except SystemExit as stop:
                code = stop.code
    finally:
        os.chdir(cwd)
    return normalise(f"exit {code}\n--- stdout\n{out.getvalue()}--- stderr\n{err.getvalue()}")


if __name__ == "__main__":
    GOLDEN.mkdir(parents=True, exist_ok=True)
    for argv in commands():
        (GOLDEN / name(argv)).write_text(run(argv), encoding="utf-8")
        print("recorded", " ".join(argv), file=sys.stderr)
