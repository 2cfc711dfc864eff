"""``asapc lint``, ``show`` and ``oracle`` as separate processes over hostile inputs, generated
here: each run is held to a memory limit (``resource.setrlimit``) and a time limit, and must
exit 0, 1 or 2 (never 70, an internal error), print no Python traceback, print no raw control
character, and keep its output within bounds. The families are those of the hardening issue:
files that are not regular, windows and deadlines beyond reason, numbers out of their domain,
deep and long expressions, unsampleable boxes, oracle misuse, machine-exhausting settings,
simulator factories, terminal escapes, big files and odd encodings."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import BASE

MEMORY = 3 * 1024**3      # bytes of address space per run (the failures seen grew to 17-24 GB)
SECONDS = 90              # wall time per run
OUTPUT = 200_000          # characters of stdout + stderr per run, plus PER_LINE for each line of input
PER_LINE = 300            # (`show` lists every declaration: its output may grow with the spec, no faster)

IS_LINUX = sys.platform.startswith("linux")


def _limits() -> None:  # in the child, before exec
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY, MEMORY))
    resource.setrlimit(resource.RLIMIT_CPU, (SECONDS, SECONDS))


def asapc(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONWARNINGS="default")
    env.pop("ASAPC_DEBUG", None)
    return subprocess.run([sys.executable, "-m", "asap_dsl.cli", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, errors="replace", timeout=SECONDS, preexec_fn=_limits, stdin=subprocess.DEVNULL)


def spec(tmp: Path, text: str, name: str = "hostile.asap") -> str:
    path = tmp / name
    path.write_text(text, encoding="utf-8")
    return str(path)


def edit(*pairs: str) -> str:
    src = BASE
    for old, new in zip(pairs[::2], pairs[1::2]):
        assert old in src, old
        src = src.replace(old, new, 1)
    return src


def task_clause(clause: str) -> str:
    return edit("deadline 30", f"deadline 30\n  {clause}")


# z never moves, so the goal is never reached: only a search (bounded in time) can tell
STUCK = ("system Stuck {\n  state x in [-10, 10] init [-5, -5]\n  state z in [-5, 5] init [0, 0]\n"
         "  action u in [-1, 1]\n  dt = 1\n  map { x = x + u, z = z }\n}\n"
         "region up = box(z in [1, 2])\ntask never { asap in up  deadline 1000000 }\n")

# name -> (how to make the input in tmp: returns the path, commands to run on it)
LINT_SHOW = (("lint",), ("show",), ("show", "--format", "json"))
ORACLE = (("oracle", "--episodes", "3", "--state-time-limit", "2"),)
CASES = {
    # 1. files that are not regular files, and sizes
    "dev-zero": (lambda tmp: "/dev/zero", LINT_SHOW),
    "fifo": (lambda tmp: (os.mkfifo(tmp / "pipe.asap"), str(tmp / "pipe.asap"))[1], LINT_SHOW),
    "directory": (lambda tmp: str(tmp), (("lint",),)),
    "missing": (lambda tmp: str(tmp / "nothing.asap"), LINT_SHOW + ORACLE),
    "eleven-megabytes": (lambda tmp: spec(tmp, BASE + "#" * (11 * 1024**2)), LINT_SHOW),
    # 2. windows and deadlines beyond any episode
    "window-1e9": (lambda tmp: spec(tmp, edit("asap in goal", "asap once[0, 1000000000] in goal",
                                              "deadline 30", "deadline 1000000")), LINT_SHOW),
    "rho-window-1e9": (lambda tmp: spec(tmp, task_clause("reward rho(window = 1000000000)")), LINT_SHOW),
    "deadline-1e9": (lambda tmp: spec(tmp, edit("deadline 30", "deadline 1000000000")), LINT_SHOW + ORACLE),
    # 3. numbers out of their domain
    "sqrt-negative": (lambda tmp: spec(tmp, edit("dt = 0.1", "dt = 0.1\n  let q = sqrt(x - 10)",
                                                 "asap in goal", "asap in goal and q < 1")), LINT_SHOW),
    "sqrt-maybe": (lambda tmp: spec(tmp, edit("asap in goal", "asap in goal and sqrt(x) < 0.5")), LINT_SHOW + ORACLE),
    "r-sat-inf": (lambda tmp: spec(tmp, task_clause("r_sat inf")), LINT_SHOW),
    "lambda-inf": (lambda tmp: spec(tmp, task_clause("reward distance(lambda_t = inf)")), LINT_SHOW),
    "inf-minus-inf": (lambda tmp: spec(tmp, edit("y' = u", "y' = u + (inf - inf)")), LINT_SHOW + ORACLE),
    # 2^2^...^2: lint-clean before, then Python's OverflowError in the oracle (exit 70)
    "power-tower": (lambda tmp: spec(tmp, edit("y' = u", "y' = u + " + "^".join(["2"] * 50))),
                    LINT_SHOW + ORACLE + (("lint", "--deep", "--samples", "2", "--deep-seconds", "2"),)),
    "diverging": (lambda tmp: spec(tmp, edit("[-5, 5]", "[-inf, inf] init [-1, 1]", "x' = y", "x' = exp(x) * 1e300")),
                  LINT_SHOW + ORACLE),
    # 4. deep and long expressions
    "sum-3000": (lambda tmp: spec(tmp, edit("y' = u", "y' = u + " + " + ".join(["0.001 * x"] * 3000))), LINT_SHOW + ORACLE),
    "and-3000": (lambda tmp: spec(tmp, edit("asap in goal", "asap in goal and " + " and ".join(["x > -9"] * 3000))),
                 LINT_SHOW),
    "lets-3000": (lambda tmp: spec(tmp, edit("dt = 0.1", "dt = 0.1\n  let l0 = x\n" + "\n".join(
        f"  let l{i} = l{i - 1} + 0.001" for i in range(1, 3000)), "asap in goal", "asap in goal and l2999 > -9")),
        LINT_SHOW),
    "formulas-1000": (lambda tmp: spec(tmp, edit("task t {", "\n".join(
        f"formula f{i} = f{i - 1} and x > -9" if i else "formula f0 = x > -9" for i in range(1000)) + "\ntask t {",
        "asap in goal", "asap in goal and f999")), LINT_SHOW),
    "parens-5000": (lambda tmp: spec(tmp, edit("y' = u", "y' = " + "(" * 5000 + "u" + ")" * 5000)), LINT_SHOW),
    "not-5000": (lambda tmp: spec(tmp, edit("asap in goal", "asap " + "not " * 5000 + "in goal")), LINT_SHOW),
    # 5. infinite or huge boxes
    "infinite-box": (lambda tmp: spec(tmp, edit("state x in [-5, 5]", "state x in [-inf, inf]")), LINT_SHOW + ORACLE),
    "huge-init": (lambda tmp: spec(tmp, edit("state x in [-5, 5]", "state x in [-inf, inf] init [-1e308, 1e308]")),
                  LINT_SHOW),
    # 6. what the oracle cannot do
    "no-action": (lambda tmp: spec(tmp, edit("  action u in [-1, 1]\n", "", "y' = u", "y' = 0")), LINT_SHOW + ORACLE),
    "avoid-covers-init": (lambda tmp: spec(tmp, edit("ball([-1, 0], 0.2)", "box(y in [-5, 5])")), LINT_SHOW + ORACLE),
    "oracle-bad-flags": (lambda tmp: spec(tmp, BASE), (
        ("oracle", "--seed", "-1"), ("oracle", "--episodes", "1000000000000"), ("oracle", "--episodes", "1e12"),
        ("oracle", "--workers", "1000"), ("oracle", "--task", ""), ("oracle", "--task", "nope"),
        ("oracle", "--state-time-limit", "inf"), ("lint", "--deep", "--samples", "0"))),
    "unreachable-deep": (lambda tmp: spec(tmp, STUCK),
                         (("lint", "--deep", "--samples", "2", "--deep-seconds", "2"),
                          ("oracle", "--episodes", "2", "--state-time-limit", "1"))),
    # 7. settings that would exhaust the machine
    "substeps-1e9": (lambda tmp: spec(tmp, edit("dt = 0.1", "dt = 0.1\n  integrator rk4(substeps = 1000000000)")),
                     LINT_SHOW + ORACLE),
    # 8. simulator factories: never imported by lint or show; oracle plans through them (a factory that
    #    ends its process is probed in a child first)
    "factory-exit": (lambda tmp: spec(tmp, edit("  ode {\n    x' = y\n    y' = u\n  }", '  simulator "sys:exit"')),
                     LINT_SHOW + ORACLE),
    "factory-system": (lambda tmp: spec(tmp, edit("  ode {\n    x' = y\n    y' = u\n  }", '  simulator "os:abort"')),
                       LINT_SHOW + ORACLE),
    # 9. terminal escapes
    "escapes": (lambda tmp: spec(tmp, edit("task t {", "task t\x1b[2J\x07 {", "system Plant", "system Pl\x1bant")),
                LINT_SHOW),
    "escape-string": (lambda tmp: spec(tmp, edit("  ode {\n    x' = y\n    y' = u\n  }", '  simulator "\x1b[31mred"')),
                      LINT_SHOW),
    # 10. many declarations
    "regions-5000": (lambda tmp: spec(tmp, BASE + "\n".join(f"region r{i} = ball([0, 0], 1)" for i in range(5000))),
                     (("lint",), ("show",))),
    "states-1000": (lambda tmp: spec(tmp, edit("  state y in [-5, 5]\n", "  state y in [-5, 5]\n" + "".join(
        f"  state s{i} in [-1, 1]\n" for i in range(1000)), "    y' = u\n", "    y' = u\n" + "".join(
        f"    s{i}' = 0\n" for i in range(1000)), "ball([1, 0], 0.5)", "ball({x: 1, y: 0}, 0.5)",
        "ball([-1, 0], 0.2)", "ball({x: -1, y: 0}, 0.2)")), (("lint",), ("show",))),
    # 11. encodings, line endings, long lines
    "bom-crlf": (lambda tmp: spec(tmp, "\ufeff" + BASE.replace("\n", "\r\n")), LINT_SHOW),
    "cr-only": (lambda tmp: spec(tmp, BASE.replace("\n", "\r")), LINT_SHOW),
    "long-line": (lambda tmp: spec(tmp, edit("asap in goal", "asap in goal and " + "x" * 2_000_000)), LINT_SHOW),
    "latin-1": (lambda tmp: (Path(tmp / "l1.asap").write_bytes(BASE.encode() + b"# caf\xe9\n"), str(tmp / "l1.asap"))[1],
                LINT_SHOW),
    "binary": (lambda tmp: (Path(tmp / "b.asap").write_bytes(bytes(range(256)) * 64), str(tmp / "b.asap"))[1], LINT_SHOW),
    "huge-centre": (lambda tmp: spec(tmp, edit("ball([1, 0], 0.5)", "ball([1e308, 0], 0.5)")), LINT_SHOW),
}


@pytest.mark.skipif(not IS_LINUX, reason="resource limits and FIFOs as on Linux")
@pytest.mark.parametrize("case", sorted(CASES))
def test_hostile_input_gets_a_clean_answer_in_bounded_time_and_memory(case, tmp_path):
    make, commands = CASES[case]
    path = make(tmp_path)
    lines = Path(path).read_bytes().count(b"\n") + 1 if Path(path).is_file() else 1
    for command in commands:
        proc = asapc(command[0], path, *command[1:], cwd=tmp_path)
        shown = f"asapc {' '.join(command)} [{case}] exited {proc.returncode}:\n{proc.stdout[-1500:]}\n{proc.stderr[-1500:]}"
        assert proc.returncode in (0, 1, 2), shown
        output = proc.stdout + proc.stderr
        assert "Traceback" not in output and "internal error" not in output, shown
        assert len(output) <= OUTPUT + PER_LINE * lines, f"{len(output)} characters of output: {shown[:500]}"
        assert "\x1b" not in output and "\x07" not in output, shown


def test_the_limits_are_real(tmp_path):
    """The harness itself: a process that outgrows the memory limit is stopped."""
    code = "x = bytearray(4 * 1024**3)"
    proc = subprocess.run([sys.executable, "-c", code], preexec_fn=_limits, capture_output=True, text=True,
                          timeout=SECONDS)
    assert proc.returncode != 0 and "MemoryError" in proc.stderr
