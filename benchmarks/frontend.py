"""Front-end speed: parse + check + lint of every spec in specs/ (not a timed test).

    python benchmarks/frontend.py [--repeat N]

Prints the time per spec (best of N runs, after one warm-up that builds the parser) and the
total, plus the one-off cost of building the LALR parser.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import asap_dsl
from asap_dsl import parser

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args()
    t0 = time.perf_counter()
    parser._lark()
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


def _time(text: str, name: str) -> float:
    t = time.perf_counter()
    asap_dsl.loads(text, name)
    return time.perf_counter() - t


if __name__ == "__main__":
    main()
