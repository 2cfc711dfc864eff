"""Shared fixtures for the front-end tests: the repository root, the specs, LANGUAGE.md and
a small valid system to build snippets on. ``ASAP_FUZZ_EXAMPLES`` sets the fuzz volume."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

import asap_dsl
from asap_dsl.program import analyse

ROOT = Path(__file__).resolve().parent.parent
SPECS = sorted((ROOT / "specs").glob("*.asap"))
# The language contract: ../shared/design/LANGUAGE.md beside the checkout when there is one, else
# the copy in tests/data (a test below keeps the two identical).
SHARED_LANGUAGE_MD = ROOT.parent / "shared" / "design" / "LANGUAGE.md"
VENDORED_LANGUAGE_MD = ROOT / "tests" / "data" / "LANGUAGE.md"
LANGUAGE_MD = Path(os.environ.get("ASAP_LANGUAGE_MD",
                                  SHARED_LANGUAGE_MD if SHARED_LANGUAGE_MD.is_file() else VENDORED_LANGUAGE_MD))
DOCS = ROOT / "docs" / "language.md"

#: Hypothesis examples per fuzz test; ``ASAP_FUZZ_EXAMPLES`` overrides the defaults.
FUZZ_EXAMPLES = int(os.environ.get("ASAP_FUZZ_EXAMPLES", "0") or 0)


def fuzz_examples(default: int) -> int:
    return FUZZ_EXAMPLES or default


# A small valid file, one item per line so that tests can point at line:col.
BASE = """\
system Plant {
  state x in [-5, 5]
  state y in [-5, 5]
  action u in [-1, 1]
  dt = 0.1
  ode {
    x' = y
    y' = u
  }
}
region goal = ball([1, 0], 0.5)
region unsafe = ball([-1, 0], 0.2)
task t {
  asap in goal
  avoid in unsafe
  deadline 30
}
"""


# A one-dimensional plant for training, evaluation and sweeps: fast to simulate and to learn on.
RAIL = """\
system Rail {
  state x in [-2, 2] init [-1.5, 1.5]
  action u in [-1, 1]
  dt = 0.1
  ode { x' = 2 * u }
}
region goal = ball([1], 0.2)
region pit = box(x in [-2, -1.8])
task go {
  asap in goal
  avoid in pit
  deadline 20
  tolerances 20, 10, 5
}
"""


def asapc(capsys, *argv):
    """Exit status, stdout and stderr of ``asapc`` run in this process (argparse's own errors exit
    through SystemExit)."""
    from asap_dsl import cli

    try:
        code = cli.main([str(a) for a in argv])
    except SystemExit as e:
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


def completed(res, steps: int) -> bool:
    """A training finished: all ``steps``, or fewer where the default's plateau rule ended it
    (validation stopped improving: a complete run, as resume and tune read it)."""
    from asap_dsl.runs import RunDir

    return res.status == "finished" and (res.steps >= steps or "plateau_step" in RunDir(res.run_dir).read_manifest())


def one_line_error(err: str) -> str:
    """The one line ``asapc: error: ...`` that ``err`` must be, no traceback."""
    assert "Traceback" not in err, err
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("asapc: error:"), err
    return lines[0]


@pytest.fixture()
def tiny(tmp_path):
    """The rail spec written to a file (runs record and check the file they were trained on)."""
    p = tmp_path / "rail.asap"
    p.write_text(RAIL)
    return p


def language_blocks() -> list[str]:
    """The fenced code blocks of LANGUAGE.md, in order."""
    text = LANGUAGE_MD.read_text(encoding="utf-8")
    return re.findall(r"^```[a-z]*\n(.*?)^```", text, re.S | re.M)


def diagnostics(src: str, name: str = "<string>"):
    """Every diagnostic of ``src`` (errors and warnings), sorted."""
    try:
        _, diags = analyse(src, name)
    except asap_dsl.SpecError as err:  # syntax errors are raised by the parser
        diags = err.diagnostics
    return diags


def codes(src: str) -> list[str]:
    return [d.code for d in diagnostics(src)]


def position(src: str, needle: str, nth: int = 0) -> tuple[int, int]:
    """1-based (line, column) of the ``nth`` occurrence of ``needle`` in ``src``."""
    at = -1
    for _ in range(nth + 1):
        at = src.index(needle, at + 1)
    line = src.count("\n", 0, at) + 1
    col = at - (src.rfind("\n", 0, at) + 1) + 1
    return line, col


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return ROOT


@pytest.fixture(scope="session")
def spec_paths() -> list[Path]:
    return SPECS


@pytest.fixture(autouse=True)
def _private_cache(tmp_path_factory, monkeypatch):
    """Oracle results cached by a test stay out of the user's cache (~/.cache/asap-dsl). Envs
    step in numpy unless ``ASAP_ENGINE`` says otherwise: in a private cache every session would
    compile every task's step again (the compiled step has its own tests, test_native.py)."""
    monkeypatch.setenv("ASAP_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "asap-cache"))
    monkeypatch.setenv("ASAP_ENGINE", os.environ.get("ASAP_ENGINE") or "numpy")
