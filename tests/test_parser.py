"""The grammar and the parser: LALR conflict-free, precedence, aliases, units, reserved words,
syntax errors in plain words at the right place."""

from __future__ import annotations

import re

import lark
import pytest

import asap_dsl
from asap_dsl import ast, lark_parser, parser
from asap_dsl.stl import ir
from conftest import BASE, ROOT, diagnostics, position

LARK_INTERNAL = re.compile(r"__ANON|\$END|\b(LPAR|RPAR|LSQB|RSQB|LBRACE|RBRACE|NAME|NUMBER|DURATION|STRING|PRIME|"
                           r"COMMA|SEMICOLON|EQUAL|COLON|STAR|SLASH|PLUS|MINUS|VBAR|BANG|AMPERSAND|LESSTHAN|MORETHAN|"
                           r"CIRCUMFLEX)\b")


def lark_internal(message: str):
    """A Lark internal name in a message (user text quoted in it does not count)."""
    if "__ANON" in message or "$END" in message:
        return True
    return LARK_INTERNAL.search(re.sub(r"'[^']*'|\"[^\"]*\"|`[^`]*`", "", message))

HOST = """system Host {
  state x in [-5, 5]
  state y in [-5, 5]
  action u in [-1, 1]
  dt = 0.1
  ode { x' = y  y' = u }
}
region goal = ball([1, 0], 0.5)
region unsafe = ball([-1, 0], 0.2)
formula p = x > 0
formula q = y > 0
formula r = in goal
"""


def text(formula: str) -> str:
    """The IR of a formula written inline, as fully parenthesised text."""
    prog = asap_dsl.loads(HOST + f"formula f = {formula}\ntask t {{ asap in goal deadline 30 }}")
    return prog.formula("f").text


def node(formula: str):
    prog = asap_dsl.loads(HOST + f"formula f = {formula}\ntask t {{ asap in goal deadline 30 }}")
    return prog.formula("f").ir


def const(expr: str) -> float:
    prog = asap_dsl.loads(f"system Hc {{ const c = {expr}\n state x in [0, 1] action u in [0, 1] dt = 1 map {{ x = u }} }}\n"
                          "region g = ball([0.5], 0.1)\ntask t { asap in g deadline 3 }")
    return prog.system.consts["c"]


def test_grammar_is_lalr_conflict_free():
    grammar = (ROOT / "grammar" / "asap.lark").read_text(encoding="utf-8")
    for start in lark_parser.START_SYMBOLS:  # a file, and a reward on its own (--reward)
        lark.Lark(grammar, parser="lalr", strict=True, start=start)  # raises on any conflict or collision
    assert lark_parser.grammar_text() == grammar  # the shipped grammar is this one


def test_reserved_words_are_the_grammar_keywords():
    kw = set(parser.keywords())
    for word in ("system", "state", "action", "const", "let", "dt", "ode", "map", "simulator", "integrator", "init",
                 "region", "ball", "box", "formula", "task", "asap", "avoid", "deadline", "tolerances", "episode",
                 "reward", "r_sat", "observe", "train", "in", "inf", "true", "false", "not", "and", "or", "implies",
                 "always", "eventually", "historically", "once", "until", "since", "G", "F", "H", "O", "U", "S"):
        assert word in kw
    for not_reserved in ("pi", "e", "sin", "sac", "rho", "exact", "rk4", "auto", "time", "x"):
        assert not_reserved not in kw


@pytest.mark.parametrize("decl, word", [
    ("const G = 9.81", "G"), ("let always = x", "always"), ("state task in [0, 1]", "task"),
    ("const r_sat = 1", "r_sat"), ("state S in [0, 1]", "S"),
])
def test_keywords_are_reserved_everywhere(decl, word):
    src = BASE.replace("  dt = 0.1", "  " + decl + "\n  dt = 0.1")
    diags = diagnostics(src)
    assert [d.code for d in diags] == ["E001"]
    d = diags[0]
    assert (d.line, d.column) == position(src, word + " ", 0 if word not in src.split(decl)[0] else 1) or word in d.message
    assert f"'{word}' is a reserved word" in d.hint


def test_keyword_after_an_operator_is_reported_at_the_keyword():
    src = HOST + "formula z = x == task\ntask t { asap in goal deadline 30 }"
    d = diagnostics(src)[0]
    assert d.code == "E001" and (d.line, d.column) == position(src, "task\n")
    assert "reserved word" in d.hint


# ---------------------------------------------------------------- precedence

@pytest.mark.parametrize("written, means, not_means", [
    ("p -> q -> r", "p -> (q -> r)", "(p -> q) -> r"),
    ("p or q -> r", "(p or q) -> r", "p or (q -> r)"),
    ("p or q and r", "p or (q and r)", "(p or q) and r"),
    ("p and q or r", "(p and q) or r", "p and (q or r)"),
    ("p and q until r", "p and (q until r)", "(p and q) until r"),
    ("p until q and r", "(p until q) and r", "p until (q and r)"),
    ("p since q or r", "(p since q) or r", "p since (q or r)"),
    ("p until q until r", "(p until q) until r", "p until (q until r)"),
    ("not p until q", "(not p) until q", "not (p until q)"),
    ("always p and q", "(always p) and q", "always (p and q)"),
    ("not p and q", "(not p) and q", "not (p and q)"),
    ("eventually[0, 3] always p", "eventually[0, 3] (always p)", "(eventually[0, 3] p)"),
    ("p or q or r", "(p or q) or r", "p or (q and r)"),
    ("p and q and r", "(p and q) and r", "p and (q or r)"),
])
def test_precedence(written, means, not_means):
    assert text(written) == text(means)
    assert text(written) != text(not_means)


def test_chains_of_and_and_or_are_one_chain_however_grouped():
    # min and max are associative: (p and q) and r, p and (q and r), p and q and r are one chain
    for written in ("p and q and r", "(p and q) and r", "p and (q and r)"):
        assert text(written) == text("p and q and r") == "x > 0 and y > 0 and in goal"
        assert len(ir.operands(node(written))) == 3
    assert text("(p or q) or r") == text("p or (q or r)") == "x > 0 or y > 0 or in goal"
    assert text("(p and q) or r") == "(x > 0 and y > 0) or in goal"


def test_precedence_structure():
    n = node("not x + 1 > 2 * y")
    assert isinstance(n, ir.Not) and isinstance(n.arg, ir.Atom) and n.arg.text == "x + 1 > 2 * y"
    states = __import__("numpy").array([[1.0, 0.0], [0.0, 1.0]])
    assert list(n.arg.robustness(states)) == [2.0, -1.0]  # rho of a > b is a - b
    n = node("p -> q -> r")
    assert isinstance(n, ir.Implies) and isinstance(n.right, ir.Implies)
    n = node("not in goal until x > 0 and y > 0")
    assert isinstance(n, ir.And) and isinstance(n.left, ir.Until) and isinstance(n.left.left, ir.Not)
    n = node("historically[0, 2] x > 0 or once y < 0")
    assert isinstance(n, ir.Or) and isinstance(n.left, ir.Historically) and isinstance(n.right, ir.Once)


@pytest.mark.parametrize("expr, value", [
    ("2 ^ 3 ^ 2", 512.0), ("-2 ^ 2", -4.0), ("1 - 2 - 3", -4.0), ("8 / 4 / 2", 1.0),
    ("1 + 2 * 3", 7.0), ("(1 + 2) * 3", 9.0), ("2 * -3", -6.0), ("+4", 4.0), ("--2", 2.0),
    ("2 ^ -1", 0.5), ("1e6", 1e6), ("2.5e-3", 2.5e-3), ("norm(3, 4)", 5.0), ("max(1, 5, 2)", 5.0),
    ("min(4, -1)", -1.0), ("atan2(1, 1) * 4", 3.141592653589793), ("pi", 3.141592653589793), ("e", 2.718281828459045),
])
def test_arithmetic_precedence_and_folding(expr, value):
    assert const(expr) == pytest.approx(value)


# ---------------------------------------------------------------- aliases

@pytest.mark.parametrize("alias, long", [
    ("G p", "always p"), ("F p", "eventually p"), ("H p", "historically p"), ("O p", "once p"),
    ("G[1, 4] p", "always[1, 4] p"), ("F[0, 2s] p", "eventually[0, 20] p"),
    ("p U q", "p until q"), ("p S q", "p since q"), ("p U[1, 3] q", "p until[1, 3] q"),
    ("! p", "not p"), ("!p", "not p"), ("p & q", "p and q"), ("p | q", "p or q"),
    ("p implies q", "p -> q"), ("p -> q", "p implies q"),
    ("!p & q | r -> p", "((not p) and q) or r -> p"),
])
def test_aliases_give_the_same_ir(alias, long):
    assert text(alias) == text(long)
    assert type(node(alias)) is type(node(long))


def test_alias_spelling_is_canonical_in_the_ast():
    module, _ = parser.parse(HOST + "formula f = G p & F q | p U q")
    body = module.formulas[-1].body
    assert isinstance(body, ast.Logic) and body.op == "or"
    assert body.left.op == "and" and body.left.left.op == "always" and body.left.right.op == "eventually"
    assert body.right.op == "until"


# ---------------------------------------------------------------- intervals and units

@pytest.mark.parametrize("interval, steps", [
    ("[0, 1.5s]", (0, 15)), ("[0, 500ms]", (0, 5)), ("[2, 7]", (2, 7)), ("[0.2s, inf]", (2, None)),
    ("[0, inf]", (0, None)), ("[100ms, 0.3s]", (1, 3)), ("[3, 3]", (3, 3)), ("[1e1, 2e1]", (10, 20)),
])
def test_interval_units(interval, steps):
    n = node(f"eventually{interval} p")
    assert (n.interval.lo, n.interval.hi) == steps


def test_no_interval_means_zero_to_inf():
    for op, cls in (("always", ir.Always), ("eventually", ir.Eventually), ("historically", ir.Historically),
                    ("once", ir.Once)):
        n = node(f"{op} p")
        assert isinstance(n, cls) and n.interval == ir.Interval(0, None)
    assert node("p until q").interval == ir.Interval(0, None)


def test_duration_tokens():
    module, _ = parser.parse(HOST + "formula f = F[0, 1.5s] p and G[0, 500ms] q and H[0, .5s] p")
    body = module.formulas[-1].body
    assert body.left.left.interval.hi == ast.Duration(1.5, "s", body.left.left.interval.hi.span)
    assert body.left.right.interval.hi.unit == "ms" and body.left.right.interval.hi.value == 500
    assert body.right.interval.hi.value == 0.5


@pytest.mark.parametrize("bad, code", [
    ("eventually[0, 0.15s] p", "E106"), ("eventually[0, 2.5] p", "E106"), ("eventually[4, 2] p", "E105"),
    ("eventually[inf, 2] p", "E117"), ("eventually[1s, 0.5s] p", "E105"),
])
def test_bad_intervals(bad, code):
    src = HOST + f"formula f = {bad}\ntask t {{ asap in goal deadline 30 }}"
    assert code in [d.code for d in diagnostics(src)]


# ---------------------------------------------------------------- equality

@pytest.mark.parametrize("op, hint", [("==", "abs(a - b) <= eps"), ("!=", "abs(a - b) > eps")])
def test_equality_refused_with_hint(op, hint):
    src = HOST + f"formula f = x {op} 1\ntask t {{ asap in goal deadline 30 }}"
    d = [d for d in diagnostics(src) if d.code == "E115"]
    assert len(d) == 1
    assert (d[0].line, d[0].column) == position(src, op)
    assert hint in d[0].hint


# ---------------------------------------------------------------- lexical

def test_comments_whitespace_and_separators():
    src = """# a comment line
system   Sep{const a=1,b=a+1;state x in[0,b]init[0,1];action u in[-1,1]   # trailing
dt=0.5;ode{x'=u;};}
region g=ball([1],0.5);;
task t{asap in g;deadline 4;tolerances 4,3,,2}
"""
    diags = diagnostics(src)
    prog = asap_dsl.loads(src.replace(",,", ","))
    assert prog.system.consts == {"a": 1.0, "b": 2.0, "dt": 0.5}  # dt is a constant too
    assert prog.task("t").tolerances == (4, 3, 2)
    assert all(d.code != "E001" for d in diags)


def test_strings_in_train_and_simulator():
    src = BASE.replace("  dt = 0.1\n  ode {\n    x' = y\n    y' = u\n  }\n", '  dt = 0.1\n  simulator "pkg.mod:make"\n')
    src = src.replace("deadline 30", 'deadline 30\n  train { algo = "td3", preset = "paper" }')
    prog = asap_dsl.loads(src)
    assert prog.system.simulator == "pkg.mod:make" and prog.system.kind == "simulator"
    assert prog.task("t").train == {"algo": "td3", "preset": "paper"}


@pytest.mark.parametrize("snippet, needle, words", [
    ("state x in [-5 5]", "5]", "expected"),
    ('simulator "abc', '"abc', "unexpected character"),
    ("dt = 0.1 @", "@", "unexpected character '@'"),
    ("ode { x = y }", "=", "expected"),
])
def test_syntax_errors_are_positioned_and_plain(snippet, needle, words):
    src = "system P {\n  " + snippet + "\n}\n"
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(src)
    [d] = info.value.diagnostics
    assert d.code == "E001" and d.severity == "error"
    assert (d.line, d.column) == position(src, needle, 0 if needle != "=" else 0)
    assert words in d.message
    assert not lark_internal(d.message), d.message
    assert not lark_internal(d.hint or "")


def test_ode_equation_without_prime_has_a_hint():
    d = diagnostics("system P {\n  state x in [0, 1]\n  ode { x = 1 }\n}\n")[0]
    assert d.hint == "an ODE equation is written x' = expr"


def test_unexpected_end_of_file():
    src = "system P {\n  state x in [0, 1]\n"
    [d] = diagnostics(src)
    assert d.code == "E001" and "end of the file" in d.message
    assert d.line == 2 and "missing" in d.hint


def test_unprintable_character():
    [d] = diagnostics("system P {\x07}")
    assert d.code == "E001" and "not printable" in d.message and (d.line, d.column) == (1, 11)


@pytest.mark.parametrize("src", [
    "task t { asap in goal deadline 30 }\n" * 2 + "x",
    "formula = in goal", "region g = ball([1, 2, 3]", "system { }", "))))", "[[[[", "system P { ode { x' } }",
    "task t { reward rho(window = ) }", "task t { episode 1.. }", "system P { state x in [0, 1] init }",
])
def test_syntax_error_messages_have_no_lark_internals(src):
    diags = diagnostics(src)
    assert diags and diags[0].code == "E001"
    for d in diags:
        assert not lark_internal(d.message), d.message
        assert d.line >= 1 and d.column >= 1


def test_deep_nesting_is_a_diagnostic_not_a_crash():
    src = HOST + "formula f = " + "(" * 3000 + "x > 0" + ")" * 3000
    diags = diagnostics(src)
    assert diags and all(d.code == "E001" for d in diags) or diags == []


def test_ast_spans_point_at_the_source():
    src = HOST + "formula f = always[0, 3] x > 0\n"
    module, _ = parser.parse(src)
    f = module.formulas[-1]
    assert (f.name_span.line, f.name_span.column) == position(src, "f = always")
    assert (f.body.op_span.line, f.body.op_span.column) == position(src, "always[0, 3]")
    assert (f.body.span.line, f.body.span.column) == position(src, "always[0, 3]")
    assert f.body.span.end_column == position(src, "x > 0\n", 1)[1] + len("x > 0")
    s = module.systems[0]
    assert [st.name for st in s.states] == ["x", "y"] and (s.states[1].span.line, s.states[1].span.column) == (3, 3)


# --------------------------------------------------------------------------- misspelt keywords
_HOST = "system A { state x in [0, 1]  dt = 0.1  map { x = x } }\n"


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("system A { stat x in [0, 1] }", "did you mean the keyword 'state'?"),
        (_HOST + "formula f = eventualy[0, 3] x < 1", "did you mean the keyword 'eventually'?"),
        (_HOST + "task t { asap x < 1  dedline 3 }", "did you mean 'deadline'?"),
    ],
)
def test_misspelt_keyword_gets_a_suggestion(text, fragment):
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(text)
    hints = [d.hint or "" for d in info.value.diagnostics]
    assert any(fragment in h for h in hints), hints


def test_misspelt_clause_is_reported_once_not_also_its_number():
    with pytest.raises(asap_dsl.SpecError) as info:
        asap_dsl.loads(_HOST + "task t { asap x < 1  dedline 3 }")
    e119 = [d for d in info.value.diagnostics if d.code == "E119"]
    assert len(e119) == 1 and "dedline" in e119[0].message


# ---------------------------------------------------------------- units written apart
@pytest.mark.parametrize("clause, fixed, at", [
    ("deadline 15 s", "15s", "s\n"), ("tolerances 10 s, 5 s", "10s", "s, 5"), ("deadline 300 ms", "300ms", "ms"),
])
def test_a_unit_apart_from_its_number_is_one_error_at_the_unit(clause, fixed, at):
    src = BASE.replace("deadline 30", "deadline 30s" if not clause.startswith("deadline") else clause).replace(
        "  avoid in unsafe\n", "  avoid in unsafe\n" + (clause + "\n" if clause.startswith("tolerances") else ""))
    found = diagnostics(src)
    errors = [d for d in found if d.is_error]
    assert errors[0].code == "E001" and f"write `{fixed}`" in errors[0].message
    assert (errors[0].line, errors[0].column) == position(src, at)
    assert all(d.code == "E001" for d in errors)  # nothing derived from a deadline read as 15 steps


def test_a_unit_apart_in_an_episode_range_is_said_in_words():
    src = BASE.replace("deadline 30", "deadline 3s\n  episode 2 s .. 3s")
    (d,) = diagnostics(src)
    assert d.code == "E001" and "write `2s`" in d.message


def test_reward_settings_take_times():
    prog = asap_dsl.loads(BASE.replace("deadline 30", "deadline 30\n  reward rho(window = 1s)"))
    assert prog.task("t").reward.params["window"] == 10
    found = diagnostics(BASE.replace("dt = 0.1", "dt = 0.1\n  integrator rk4(substeps = 2s)"))
    assert [(d.code, "substeps takes a number, not a time" in d.message) for d in found if d.is_error] == [("E117", True)]


# ---------------------------------------------------------------- conditionals and the unit `steps`

def test_conditional_parses_as_the_loosest_expression():
    src = "system P { let w = if x > 0 and y <= 1 then -x else if y == 2 then clip(y, 0, 1) else 3 }"
    module, diags = parser.parse(src)
    e = module.systems[0].lets[0].value
    assert not diags and isinstance(e, ast.Conditional)
    assert isinstance(e.test, ast.Logic) and e.test.op == "and"
    assert isinstance(e.then_, ast.Unary) and isinstance(e.else_, ast.Conditional)
    assert e.else_.test.op == "==" and e.else_.then_.func == "clip"
    # Inside arithmetic it is written in parentheses; the else branch takes what follows it.
    inner = parser.parse("system P { let w = 1 + (if x > 0 then 2 else 3) * 4 }")[0].systems[0].lets[0].value
    assert inner.op == "+" and isinstance(inner.right.left, ast.Conditional)
    greedy = parser.parse("system P { let w = if x > 0 then 2 else 3 + 4 }")[0].systems[0].lets[0].value
    assert isinstance(greedy, ast.Conditional) and greedy.else_.op == "+"
    assert e.span == ast.Span(1, src.index("if") + 1, 1, src.index("3 }") + 2)


def test_if_then_else_are_reserved():
    assert {"if", "then", "else"} <= set(parser.keywords())
    for word in ("if", "then", "else"):
        diags = diagnostics(BASE.replace("  dt = 0.1", f"  const {word} = 1\n  dt = 0.1"))
        assert [d.code for d in diags] == ["E001"] and f"'{word}' is a reserved word" in diags[0].hint


@pytest.mark.parametrize("written, steps", [("deadline 200 steps", 200), ("deadline 1 step", 1), ("deadline 30", 30)])
def test_deadline_in_steps_with_the_unit_written_out(written, steps):
    prog = asap_dsl.loads(BASE.replace("deadline 30", written + "\n  tolerances 1 steps, 1\n  episode 1 steps..1"))
    assert prog.task("t").deadline == steps and prog.task("t").tolerances == (1, 1)
    assert node("eventually[0 steps, 3 steps] p").interval == ir.Interval(0, 3)


def test_steps_stays_a_name_where_no_number_precedes_it():
    prog = asap_dsl.loads(BASE.replace("deadline 30", "deadline 30 steps\n  train { steps = 4000 }"))
    assert prog.task("t").train["steps"] == 4000
    diags = diagnostics(BASE.replace("asap in goal", "asap in goal\n  steps"))
    assert [d.code for d in diags] == ["E119"]  # a lone word, as before
