"""Fuzz the front end: token soup, random text and mutations of every spec and LANGUAGE.md
example. ``asap_dsl.loads`` returns a Program or raises SpecError with positioned, plain-word
diagnostics and a report that formats; never any other exception. A Program that loads runs a
few steps of each task's batched environment with finite rewards, observations and info.

Volume: ``ASAP_FUZZ_EXAMPLES`` examples per test (default below, a few thousand in all)."""

from __future__ import annotations

import re
import time

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import numpy as np

import asap_dsl
from asap_dsl import parser
from asap_dsl.env import make_vec_env
from conftest import SPECS, fuzz_examples, language_blocks
from test_parser import lark_internal

STATS = {"inputs": 0, "ran": 0, "worst": 0.0, "worst_input": ""}

parser.get_parser()  # build the parser once, so that the timing below is per input
SEEDS = [p.read_text(encoding="utf-8") for p in SPECS] + language_blocks()
TOKEN_RE = re.compile(r"\s+|#[^\n]*|\w+'?|\.\.|->|<=|>=|==|!=|\"[^\"\n]*\"|.", re.S)
SEED_TOKENS = [TOKEN_RE.findall(s) for s in SEEDS]

PUNCT = list("{}()[],;:=+-*/^<>!&|'\".#") + ["..", "->", "<=", ">=", "==", "!=", "\n", " ", "\t"]
WORDS = sorted(parser.keywords()) + ["x", "y", "goal", "unsafe", "sin", "norm", "sac", "rho", "auto", "exact",
                                     "rk4", "time", "pi", "e", "reach", "omega", "window"]
NUMBERS = ["0", "1", "30", "0.1", "1e6", "2.5e-3", ".5", "3s", "500ms", "1.5s", "1e400", "-1", "0s"]
SETTINGS = dict(deadline=None, suppress_health_check=list(HealthCheck), database=None)


def check_one(text: str) -> None:
    t0 = time.perf_counter()
    try:
        prog = asap_dsl.loads(text, name="fuzz.asap")
    except asap_dsl.SpecError as err:
        assert err.diagnostics, "a SpecError without diagnostics"
        for d in err.diagnostics:
            assert d.line >= 1 or (d.line == 0 and d.code == "E002"), d
            assert d.column >= 1 or d.line == 0, d
            assert isinstance(d.message, str) and d.message
            assert not lark_internal(d.message), d.message
            assert "__ANON" not in (d.hint or "") and "$END" not in (d.hint or ""), d.hint
            assert d.severity in ("error", "warning")
        assert err.errors
        assert isinstance(str(err), str)
    else:
        assert isinstance(prog, asap_dsl.Program)
        for name in prog.tasks:
            prog.task(name).spec.text  # noqa: B018 - builds the spec
        run_briefly(prog)
    finally:
        dt = time.perf_counter() - t0
        STATS["inputs"] += 1
        if dt > STATS["worst"]:
            STATS["worst"], STATS["worst_input"] = dt, text[:200]


def run_briefly(prog: asap_dsl.Program, steps: int = 4) -> None:
    """A spec that loads runs: every task's batched environment takes a few steps with random
    actions, and every reward, observation and info value is finite (a NaN ends the episode as
    ``non_finite``). MuJoCo systems are left to test_sim (building one per input is slow)."""
    if prog.system.kind == "simulator":
        return
    for name in prog.tasks:
        env = make_vec_env(prog, task=name, num_envs=3, seed=0)
        obs = env.reset()
        assert np.isfinite(obs).all()
        rng = np.random.default_rng(0)
        for _ in range(steps):
            actions = rng.uniform(env.action_space.low, env.action_space.high, size=(3,) + env.action_space.shape)
            obs, rewards, _, infos = env.step(actions)
            assert np.isfinite(obs).all() and np.isfinite(rewards).all(), (obs, rewards)
            for info in infos:
                for key, value in info.items():
                    if isinstance(value, (float, np.ndarray)):
                        assert np.isfinite(value).all(), (key, value)
        STATS["ran"] += 1


token = st.one_of(st.sampled_from(PUNCT), st.sampled_from(WORDS), st.sampled_from(NUMBERS),
                  st.text(min_size=1, max_size=3))


@settings(max_examples=fuzz_examples(600), **SETTINGS)
@given(st.lists(token, max_size=60))
def test_token_soup(tokens):
    check_one(" ".join(tokens))
    check_one("".join(tokens))


@settings(max_examples=fuzz_examples(300), **SETTINGS)
@given(st.binary(max_size=200))
def test_random_bytes(data):
    check_one(data.decode("utf-8", errors="replace"))
    check_one(data.decode("latin-1"))


@st.composite
def mutated(draw):
    i = draw(st.integers(0, len(SEEDS) - 1))
    tokens = list(SEED_TOKENS[i])
    for _ in range(draw(st.integers(1, 4))):
        if not tokens:
            break
        k = draw(st.integers(0, len(tokens) - 1))
        op = draw(st.sampled_from(["delete", "duplicate", "swap", "insert", "replace", "char", "truncate"]))
        if op == "delete":
            del tokens[k]
        elif op == "duplicate":
            tokens.insert(k, tokens[k])
        elif op == "swap":
            j = draw(st.integers(0, len(tokens) - 1))
            tokens[k], tokens[j] = tokens[j], tokens[k]
        elif op == "insert":
            tokens.insert(k, draw(token))
        elif op == "replace":
            tokens[k] = draw(token)
        elif op == "char":
            text = "".join(tokens)
            at = draw(st.integers(0, len(text)))
            how = draw(st.sampled_from(["del", "ins", "dup"]))
            if how == "del":
                text = text[:at] + text[at + 1:]
            elif how == "ins":
                text = text[:at] + draw(st.characters()) + text[at:]
            else:
                text = text[:at] + text[at:at + 5] + text[at:]
            tokens = TOKEN_RE.findall(text)
        else:
            tokens = tokens[:k]
    return "".join(tokens)


@settings(max_examples=fuzz_examples(1500), **SETTINGS)
@given(mutated())
def test_mutated_specs_and_examples(text):
    check_one(text)


def test_seeds_themselves():
    for text in SEEDS:
        check_one(text)
    for text in SEEDS:
        for cut in range(0, len(text), max(1, len(text) // 60)):
            check_one(text[:cut])


def test_report_fuzz_volume(capsys):
    # runs last in this file (pytest keeps definition order): the figures for the report
    with capsys.disabled():
        print(f"\n[fuzz] {STATS['inputs']} inputs ({STATS['ran']} environments run), slowest {STATS['worst'] * 1000:.1f} ms: {STATS['worst_input'][:80]!r}")
