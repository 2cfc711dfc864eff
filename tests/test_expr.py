"""Expressions: the numpy code generator against direct math evaluation, and the soundness of
interval enclosures (every point of a box evaluates inside the enclosure of the box)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import asap_dsl
from asap_dsl import ast, parser
from asap_dsl.expr import FUNCTION_ARITY, Symbols, compile_batched, degree, evaluate_constant, interval_range
from asap_dsl.intervals import FUNCTIONS, Interval
from conftest import fuzz_examples

SYMBOLS = Symbols({"k": 2.0}, {"x": 0, "y": 1, "z": 2}, {}, {})
SETTINGS = settings(max_examples=fuzz_examples(60), deadline=None, suppress_health_check=[HealthCheck.too_slow])


def parse_expr(text: str):
    module, _ = parser.parse(f"system P {{ let w = {text} }}")
    return module.systems[0].lets[0].value


def numpy_eval(text: str, points: np.ndarray) -> np.ndarray:
    with np.errstate(all="ignore"):
        return compile_batched([parse_expr(text)], SYMBOLS)(points)[..., 0]


# function -> (expression, direct python evaluation, sampling box for x, y, z)
PY = {
    "sin": ("sin(x)", lambda x, y, z: math.sin(x), (-10, 10)),
    "cos": ("cos(x)", lambda x, y, z: math.cos(x), (-10, 10)),
    "tan": ("tan(x)", lambda x, y, z: math.tan(x), (-1.5, 1.5)),
    "asin": ("asin(x)", lambda x, y, z: math.asin(x), (-1, 1)),
    "acos": ("acos(x)", lambda x, y, z: math.acos(x), (-1, 1)),
    "atan": ("atan(x)", lambda x, y, z: math.atan(x), (-10, 10)),
    "atan2": ("atan2(y, x)", lambda x, y, z: math.atan2(y, x), (-3, 3)),
    "sinh": ("sinh(x)", lambda x, y, z: math.sinh(x), (-5, 5)),
    "cosh": ("cosh(x)", lambda x, y, z: math.cosh(x), (-5, 5)),
    "tanh": ("tanh(x)", lambda x, y, z: math.tanh(x), (-5, 5)),
    "exp": ("exp(x)", lambda x, y, z: math.exp(x), (-5, 5)),
    "log": ("log(x)", lambda x, y, z: math.log(x), (0.01, 10)),
    "sqrt": ("sqrt(x)", lambda x, y, z: math.sqrt(x), (0, 10)),
    "abs": ("abs(x - y)", lambda x, y, z: abs(x - y), (-3, 3)),
    "min": ("min(x, y, z)", lambda x, y, z: min(x, y, z), (-3, 3)),
    "max": ("max(x, y)", lambda x, y, z: max(x, y), (-3, 3)),
    "norm": ("norm(x, y, z)", lambda x, y, z: math.sqrt(x * x + y * y + z * z), (-3, 3)),
    "clip": ("clip(x, y - 1, y + 1)", lambda x, y, z: min(max(x, y - 1), y + 1), (-3, 3)),
}
OPS = {
    "add": ("x + y", lambda x, y, z: x + y, (-3, 3)),
    "sub": ("x - y - z", lambda x, y, z: x - y - z, (-3, 3)),
    "mul": ("x * y * k", lambda x, y, z: x * y * 2.0, (-3, 3)),
    "div": ("x / y", lambda x, y, z: x / y, (0.5, 3)),
    "neg": ("-x + -(y * z)", lambda x, y, z: -x + -(y * z), (-3, 3)),
    "pow2": ("x ^ 2", lambda x, y, z: x ** 2, (-3, 3)),
    "pow3": ("x ^ 3", lambda x, y, z: x ** 3, (-3, 3)),
    "pow-1": ("y ^ -1", lambda x, y, z: y ** -1, (0.5, 3)),
    "powreal": ("y ^ 0.5", lambda x, y, z: y ** 0.5, (0, 3)),
    "powvar": ("y ^ z", lambda x, y, z: y ** z, (0.1, 3)),
    "nested": ("sin(x) * cos(y) + exp(-z^2) / (1 + x^2)",
               lambda x, y, z: math.sin(x) * math.cos(y) + math.exp(-z ** 2) / (1 + x ** 2), (-3, 3)),
    "consts": ("pi * x + e", lambda x, y, z: math.pi * x + math.e, (-3, 3)),
    # Conditionals: tests of comparisons joined by and/or/not/->, nested, inside arithmetic.
    "if": ("if x > y and not (z <= 0) or x == 1 then x - y else clip(z, -1, 1) * y",
           lambda x, y, z: x - y if (x > y and not z <= 0) or x == 1 else min(max(z, -1), 1) * y, (-3, 3)),
    "if_nested": ("1 + (if x < 0 then -x else if y >= z -> x != y then y ^ 2 else 0)",
                  lambda x, y, z: 1 + (-x if x < 0 else (y ** 2 if (not y >= z) or x != y else 0)), (-3, 3)),
    "if_constant": ("if 1 < 2 then x else y", lambda x, y, z: x, (-3, 3)),
}
CASES = {**PY, **OPS}


def test_every_function_is_covered():
    assert set(PY) == set(FUNCTION_ARITY) == set(FUNCTIONS)


@pytest.mark.parametrize("name", sorted(CASES))
def test_numpy_codegen_matches_math(name):
    text, py, (lo, hi) = CASES[name]
    rng = np.random.default_rng(hash(name) % 2**32)
    pts = rng.uniform(lo, hi, size=(200, 3))
    got = numpy_eval(text, pts)
    want = np.array([py(*p) for p in pts])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    # batched over any leading shape
    assert numpy_eval(text, pts.reshape(20, 10, 3)).shape == (20, 10)


@pytest.mark.parametrize("name", sorted(CASES))
def test_constant_folding_matches_math(name):
    text, py, (lo, hi) = CASES[name]
    x, y, z = lo + 0.3 * (hi - lo), lo + 0.6 * (hi - lo), lo + 0.9 * (hi - lo)
    values = {"x": f"({x!r})", "y": f"({y!r})", "z": f"({z!r})"}
    folded = evaluate_constant(parse_expr(re.sub(r"\b[xyz]\b", lambda m: values[m.group()], text)), {"k": 2.0})
    assert folded == pytest.approx(py(x, y, z), rel=1e-12, abs=1e-12)


def _sound(text: str, box, points: np.ndarray) -> None:
    enc = interval_range(parse_expr(text), SYMBOLS, box)
    assert enc.lo <= enc.hi or (math.isnan(enc.lo) is False and math.isnan(enc.hi) is False)
    vals = numpy_eval(text, points)
    vals = vals[np.isfinite(vals)]
    slack = 1e-9 * (1 + np.abs(vals))
    bad = vals[(vals < enc.lo - slack) | (vals > enc.hi + slack)]
    assert bad.size == 0, f"{text} over {box}: {bad[:5]} outside [{enc.lo}, {enc.hi}]"


def boxes(lo=-12.0, hi=12.0, max_width=14.0):
    def one():
        return st.tuples(st.floats(lo, hi), st.floats(0, max_width)).map(lambda t: (t[0], t[0] + t[1]))
    return st.tuples(one(), one(), one())


@pytest.mark.parametrize("name", sorted(CASES))
@SETTINGS
@given(box=boxes(), seed=st.integers(0, 2**32 - 1))
def test_interval_enclosure_is_sound(name, box, seed):
    text = CASES[name][0]
    rng = np.random.default_rng(seed)
    lo = np.array([b[0] for b in box])
    hi = np.array([b[1] for b in box])
    pts = rng.uniform(lo, hi, size=(256, 3))
    pts = np.concatenate([pts, lo[None], hi[None]])  # the corners matter for monotone pieces
    _sound(text, box, pts)


@pytest.mark.parametrize("text, box, expected", [
    ("sin(x)", (0, math.pi), (0.0, 1.0)),                      # across the peak
    ("sin(x)", (math.pi, 2 * math.pi), (-1.0, 0.0)),           # across the trough
    ("sin(x)", (0.1, 0.2), (math.sin(0.1), math.sin(0.2))),    # monotone piece: exact
    ("cos(x)", (-1, 1), (math.cos(1), 1.0)),                   # across 0
    ("cos(x)", (3, 3.5), (-1.0, max(math.cos(3), math.cos(3.5)))),
    ("cos(x)", (-100, 100), (-1.0, 1.0)),
    ("x ^ 2", (-2, 1), (0.0, 4.0)),                            # even power across 0
    ("x ^ 2", (-3, -2), (4.0, 9.0)),
    ("x ^ 3", (-2, 1), (-8.0, 1.0)),                           # odd power is monotone
    ("x ^ 4", (-1, 2), (0.0, 16.0)),
    ("abs(x)", (-3, 1), (0.0, 3.0)),
    ("cosh(x)", (-1, 2), (1.0, math.cosh(2))),
    ("sqrt(x)", (4, 9), (2.0, 3.0)),
    ("norm(x, y, z)", (-1, 1), (0.0, math.sqrt(3))),
])
def test_interval_known_enclosures(text, box, expected):
    enc = interval_range(parse_expr(text), SYMBOLS, [box] * 3)
    assert enc.lo == pytest.approx(expected[0], abs=1e-12)
    assert enc.hi == pytest.approx(expected[1], abs=1e-12)


@pytest.mark.parametrize("text, box", [("1 / x", (-1, 2)), ("y / x", (0, 0)), ("1 / x", (0, 1)), ("x ^ -2", (-1, 1))])
def test_division_by_interval_containing_zero(text, box):
    enc = interval_range(parse_expr(text), SYMBOLS, [box, (1, 2), (1, 2)])
    assert enc.hi == math.inf
    assert enc.lo in (-math.inf, 0.0, 1.0) or enc.lo <= 1.0
    pts = np.random.default_rng(0).uniform([box[0], 1, 1], [box[1], 2, 2], size=(500, 3))
    _sound(text, [box, (1, 2), (1, 2)], pts)


@pytest.mark.parametrize("text, box, expected", [
    ("if x > 2 then x else -x", [(3, 4), (0, 1), (0, 1)], (3.0, 4.0)),       # decided: the then branch
    ("if x > 2 then x else -x", [(0, 1), (0, 1), (0, 1)], (-1.0, 0.0)),      # decided: the else branch
    ("if x > 2 then x else -x", [(1, 4), (0, 1), (0, 1)], (-4.0, 4.0)),      # undecided: the hull of both
    ("if x > 0 and y < 0 then 1 else 2", [(1, 2), (2, 3), (0, 1)], (2.0, 2.0)),
    ("if x > 0 or y < 0 then 1 else 2", [(1, 2), (-1, 3), (0, 1)], (1.0, 1.0)),
    ("if not (x <= y) then 1 else 2", [(0, 1), (2, 3), (0, 1)], (2.0, 2.0)),
    ("clip(x, -1, 1)", [(-5, 0.5), (0, 1), (0, 1)], (-1.0, 0.5)),
    ("clip(x, y, z)", [(-5, 5), (0, 1), (2, 3)], (0.0, 3.0)),
])
def test_interval_conditional_and_clip(text, box, expected):
    enc = interval_range(parse_expr(text), SYMBOLS, box)
    assert (enc.lo, enc.hi) == expected


def test_interval_arithmetic_operators():
    a, b = Interval(-1, 2), Interval(3, 4)
    assert a + b == Interval(2, 6) and a - b == Interval(-5, -1) and -a == Interval(-2, 1)
    assert a * b == Interval(-4, 8) and b / Interval(1, 2) == Interval(1.5, 4)
    assert 1 - a == Interval(-1, 2) and 2 * a == Interval(-2, 4)
    assert Interval(0, 0) * Interval(-math.inf, math.inf) == Interval(0, 0)


def test_variable_exponent_with_negative_base_is_sound():
    box = [(-2.0, -1.0), (1.5, 2.5), (0, 1)]
    pts = np.array([[-2.0, 2.0, 0.0], [-1.0, 2.0, 0.0], [-1.5, 2.0, 0.0]])
    _sound("x ^ y", box, pts)


@pytest.mark.parametrize("text, deg", [("x + y", 1), ("k * x - 3", 1), ("x * y", 2), ("x ^ 2", 2), ("sin(x)", math.inf),
                                        ("x / k", 1), ("x / y", math.inf), ("sin(k) * x", 1), ("2", 0),
                                        ("clip(x, 0, 1)", math.inf), ("if x > 0 then x else 2 * x", math.inf),
                                        ("(if k > 1 then 3 else 4) * x", 1)])
def test_degree(text, deg):
    assert degree(parse_expr(text), SYMBOLS) == deg


def test_interval_power_saturates_instead_of_overflowing():
    import asap_dsl
    from asap_dsl.intervals import Interval

    assert Interval(-1e300, 1e300) ** 2 == Interval(0.0, float("inf"))
    assert Interval(-1e300, 2.0) ** 3 == Interval(float("-inf"), 8.0)
    prog = asap_dsl.loads("system A { state x in [-1e300, 1e300]  action u in [-1, 1]  dt = 1  map { x = x + u } }\n"
                          "region g = ball([0], 1)\ntask t { asap in g  deadline 3 }")
    assert prog.task("t").rho_bounds == (float("-inf"), 1.0)


@pytest.mark.parametrize("kind, n", [("sum", 300), ("lets", 2000)])
def test_long_sums_and_let_chains_compile_and_run(kind, n):
    """Generated code is straight-line: no nested parentheses for Python's parser, no recursion."""
    head = "system Deep {\n  state x in [-1, 1] init [-0.5, 0.5]\n  action u in [-1, 1]\n  dt = 0.1\n  ode { x' = u }\n"
    if kind == "sum":
        body, last = "  let s = " + " + ".join("x" for _ in range(n)) + "\n", "s"
    else:
        body = "\n".join(f"  let l{i} = l{i - 1} + 1" if i else "  let l0 = x" for i in range(n)) + "\n"
        last = f"l{n - 1}"
    prog = asap_dsl.loads(head + body + f"}}\nregion g = ball([0.5], 0.1)\ntask t {{ asap in g and {last} > 0  deadline 10 }}\n")
    venv = asap_dsl.make_vec_env(prog, "t", num_envs=4, seed=0)
    venv.reset()
    _, r, _, _ = venv.step_arrays(np.full((4, 1), 0.5))
    assert np.isfinite(r).all()
    f = compile_batched([ast.Name(last, prog.system.lets[last].span)], prog.system.symbols)
    expect = 0.3 * n if kind == "sum" else 0.3 + (n - 1)
    assert f(np.array([[0.3]]), None)[0, 0] == pytest.approx(expect)
