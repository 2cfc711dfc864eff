"""Front-end speed: parse + check + lint of every spec in specs/, and how lint scales.

    python benchmarks/frontend.py [--repeat N] [--sizes 100,1000,5000,20000]

Prints the time per spec (best of N runs, after one warm-up that builds the parser) and the
total, plus the one-off cost of building the LALR parser. Then, for specs of 100 to 20,000
declarations of one kind (unused regions, states, lets, formulas, constants), the time of
`asapc lint` (parse, check, lint rules, every diagnostic formatted) per declaration: lint is
linear when that stays flat. The ratio printed is the time per declaration at the largest size
over that at the smallest (the peer: the same code on a small spec); PASS when it is below 2.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import asap_dsl
from asap_dsl import parser

ROOT = Path(__file__).resolve().parent.parent


HEAD = """system Plant {
  state x in [-5, 5]
  state y in [-5, 5]
  action u in [-1, 1]
  dt = 0.1
%s  ode {
    x' = y
    y' = u
%s  }
}
region goal = ball({x: 1, y: 0}, 0.5)
%s
task t {
  asap in goal%s
  deadline 30
}
"""


def generated(kind: str, n: int) -> str:
    """A spec with ``n`` declarations of ``kind`` (each one line)."""
    if kind == "unused regions":
        return HEAD % ("", "", "\n".join(f"region r{i} = ball({{x: {i % 5}, y: 0}}, 1)" for i in range(n)), "")
    if kind == "states":
        return HEAD % ("".join(f"  state s{i} in [-1, 1]\n" for i in range(n)), "".join(f"    s{i}' = -s{i}\n" for i in range(n)), "", "")
    if kind == "lets":
        lets = "  let l0 = x\n" + "".join(f"  let l{i} = l{i - 1} + 0.001\n" for i in range(1, n))
        return HEAD % (lets, "", "", f" and l{n - 1} > -9")
    if kind == "formulas":
        fs = "formula f0 = x > -9\n" + "".join(f"formula f{i} = f{i - 1} and x > -9\n" for i in range(1, n))
        return HEAD % ("", "", fs, f" and f{n - 1}")
    if kind == "constants":
        return HEAD % ("".join(f"  const c{i} = {i} * 0.5\n" for i in range(n)), "", "", "")
    raise ValueError(kind)


def lint_seconds(text: str) -> float:
    """Wall time of what `asapc lint` does with a file's text: analyse, then format every diagnostic."""
    from asap_dsl.diagnostics import format_report
    from asap_dsl.program import analyse

    t = time.perf_counter()
    try:
        _, diagnostics = analyse(text, "generated.asap")
    except asap_dsl.SpecError as err:
        diagnostics = err.diagnostics
    format_report(diagnostics, {"generated.asap": text}, limit=0)
    return time.perf_counter() - t


def scaling(sizes: list[int]) -> bool:
    print(f"\nlint time per declaration (µs), sizes {', '.join(f'{n:,}' for n in sizes)}:")
    ok = True
    for kind in ("unused regions", "states", "lets", "formulas", "constants"):
        per = []
        for n in sizes:
            text = generated(kind, n)
            best = min(lint_seconds(text) for _ in range(3 if n <= 1000 else 1))
            per.append(best / n * 1e6)
        ratio = per[-1] / per[0]
        ok &= ratio < 2
        cells = "  ".join(f"{p:8.1f}" for p in per)
        print(f"  {kind:<15} {cells}   ratio {ratio:4.2f} ({'PASS' if ratio < 2 else 'FAIL'})")
    return ok


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--sizes", default="100,1000,5000,20000", help="declaration counts for the scaling table")
    args = ap.parse_args()
    t0 = time.perf_counter()
    parser.get_parser()
    print(f"parser build (once per process): {(time.perf_counter() - t0) * 1e3:8.1f} ms")
    specs = sorted((ROOT / "specs").glob("*.asap"))
    total = 0.0
    for path in specs:
        text = path.read_text(encoding="utf-8")
        asap_dsl.loads(text, str(path))  # warm-up
        best = min(_time(text, str(path)) for _ in range(args.repeat))
        total += best
        print(f"{path.name:<20} {best * 1e3:8.2f} ms  ({len(text.splitlines())} lines)")
    print(f"{'total':<20} {total * 1e3:8.2f} ms for {len(specs)} specs (parse + check + lint, best of {args.repeat})")
    ok = scaling([int(v) for v in args.sizes.split(",")])
    print(f"\nlint scales linearly: {'PASS' if ok else 'FAIL'} (time per declaration at the largest size < 2x the smallest)")


def _time(text: str, name: str) -> float:
    t = time.perf_counter()
    asap_dsl.loads(text, name)
    return time.perf_counter() - t


if __name__ == "__main__":
    main()
