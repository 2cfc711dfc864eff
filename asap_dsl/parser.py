"""Source text to AST: the Lark grammar, positioned syntax errors in plain words.

The grammar lives in ``grammar/asap.lark`` (shipped inside the package as
``asap_dsl/grammar/asap.lark``); the LALR parser is built once per process.
"""

from __future__ import annotations

import functools
import re
from importlib import resources
from pathlib import Path
from typing import Any, Optional

import lark
from lark import Token, Transformer, v_args

from . import ast
from .diagnostics import Collector, Diagnostic, Span, SpecError, make
from .limits import LIMITS

_CANONICAL = {
    "->": "implies", "implies": "implies",
    "or": "or", "|": "or",
    "and": "and", "&": "and",
    "always": "always", "G": "always",
    "eventually": "eventually", "F": "eventually",
    "historically": "historically", "H": "historically",
    "once": "once", "O": "once",
    "until": "until", "U": "until",
    "since": "since", "S": "since",
}

_TASK_CLAUSES = ("asap", "avoid", "deadline", "tolerances", "episode", "reward", "r_sat", "observe", "init", "train")

# Plain words for the grammar's named terminals (punctuation and keywords print as themselves).
_TERMINAL_WORDS = {
    "NAME": "a name",
    "NUMBER": "a number",
    "DURATION": "a time such as 3s or 500ms",
    "STRING": 'a string in double quotes',
    "PRIME": "a prime (')",
    "$END": "the end of the file",
}


def _grammar_text() -> str:
    # Installed: the grammar ships inside the package. From a source checkout: grammar/asap.lark.
    try:
        return resources.files("asap_dsl").joinpath("grammar/asap.lark").read_text(encoding="utf-8")
    except (FileNotFoundError, ModuleNotFoundError, NotADirectoryError):
        here = Path(__file__).resolve().parent.parent / "grammar" / "asap.lark"
        return here.read_text(encoding="utf-8")


@functools.lru_cache(maxsize=None)
def keywords() -> dict[str, str]:
    """Reserved words of the language (every keyword of the grammar) -> their terminal names."""
    return {t.pattern.value: t.name for t in _lark().terminals
            if isinstance(t.pattern, lark.lexer.PatternStr) and t.pattern.value.isidentifier()}


def _reserve_keywords(tok: Token) -> Token:
    # The contextual lexer reads a keyword as a NAME wherever the keyword itself cannot stand
    # (`const G = 9.81`, `state task in ...`). Keywords are reserved: give the token its keyword
    # type back, so that the parser reports "'G' is a reserved word" instead of accepting a name
    # that is unusable elsewhere.
    kind = keywords().get(tok.value)
    if kind is not None:
        tok.type = kind
    return tok


@functools.lru_cache(maxsize=None)
def _lark() -> lark.Lark:
    # cache=True keeps the built LALR tables on disk, keyed by the grammar and the options: a cold
    # `asapc lint` then loads them instead of rebuilding them.
    return lark.Lark(_grammar_text(), parser="lalr", propagate_positions=True, maybe_placeholders=True,
                     lexer_callbacks={"NAME": _reserve_keywords}, cache=True)


@functools.lru_cache(maxsize=None)
def _terminal_patterns() -> dict[str, str]:
    """Terminal name -> how to show it to a user."""
    out = {}
    for t in _lark().terminals:
        if t.name in _TERMINAL_WORDS:
            out[t.name] = _TERMINAL_WORDS[t.name]
        elif isinstance(t.pattern, lark.lexer.PatternStr):
            out[t.name] = f"'{t.pattern.value}'"
        else:
            out[t.name] = t.name.lower()
    out["$END"] = _TERMINAL_WORDS["$END"]
    return out


def _describe_expected(names: set[str]) -> str:
    words = _terminal_patterns()
    shown = sorted({words.get(n, n.lower()) for n in names if not n.startswith("__") or n in words})
    # Anonymous punctuation (__ANON_n) is mapped through its pattern above; never print raw names.
    shown = [s for s in shown if not s.startswith("__")]
    if not shown:
        return ""
    if len(shown) > 8:
        return "expected one of " + ", ".join(shown[:8]) + ", ..."
    if len(shown) == 1:
        return "expected " + shown[0]
    return "expected " + ", ".join(shown[:-1]) + " or " + shown[-1]


def _describe_token(tok: Token) -> str:
    if tok.type == "$END":
        return "the end of the file"
    if tok.type == "NAME":
        return f"name '{tok}'"
    if tok.type in ("NUMBER", "DURATION"):
        return f"number {tok}"
    if tok.type == "STRING":
        return f"string {tok}"
    if tok.isidentifier():
        return f"keyword '{tok}'"
    return f"'{tok}'"


def _span_of_token(tok: Token) -> Span:
    line = tok.line or 1
    col = tok.column or 1
    end_line = tok.end_line or line
    end_col = tok.end_column or col + max(1, len(tok))
    return Span(line, col, end_line, end_col)


def _syntax_diagnostic(err: lark.exceptions.LarkError, text: str, file: str) -> Diagnostic:
    lines = text.splitlines() or [""]
    if isinstance(err, lark.exceptions.UnexpectedCharacters):
        ch = text[err.pos_in_stream] if err.pos_in_stream < len(text) else ""
        what = f"unexpected character {ch!r}" if ch.isprintable() else f"unexpected character {ch!r} (not printable)"
        hint = None
        if ch == '"':
            hint = "strings must end on the same line with a closing double quote"
        elif ch == ".":
            hint = "write a number with a digit before the point (0.5), or `a..b` for an episode range"
        span = Span(err.line, err.column, err.line, err.column + 1)
        return make("E001", what, span, file, hint)
    if isinstance(err, lark.exceptions.UnexpectedToken):
        tok = err.token
        if tok.type == "$END":
            line = len(lines)
            col = len(lines[-1]) + 1 if lines else 1
            span = Span(line, col, line, col + 1)
        else:
            span = _span_of_token(tok)
        spaced = _spaced_unit_before(tok, text)
        if spaced is not None:  # `episode 2 s .. 15s`: the unit apart from its number
            return make("E001", f"write `{spaced}{tok}`: a unit goes right after its number, with no space", span, file)
        expected = _describe_expected(set(err.expected))
        message = f"unexpected {_describe_token(tok)}" + (f"; {expected}" if expected else "")
        hint = None
        if tok.type != "NAME" and tok.isidentifier() and "NAME" in err.expected:
            hint = f"'{tok}' is a reserved word of the language: it cannot name anything, nor be read as a value"
        elif tok.type == "$END":
            hint = "a '}', ')' or ']' may be missing"
        elif tok == "=" and "PRIME" in err.expected:
            hint = "an ODE equation is written x' = expr"
        else:
            hint = _misspelt_keyword_hint(tok, err.expected, text)
        return make("E001", message, span, file, hint)
    if isinstance(err, lark.exceptions.UnexpectedEOF):
        line = len(lines)
        col = len(lines[-1]) + 1 if lines else 1
        return make("E001", "unexpected end of the file", Span(line, col, line, col + 1), file, "a '}', ')' or ']' may be missing")
    return make("E001", "the text could not be parsed", Span(1, 1, 1, 2), file)


def _spaced_unit_before(tok: Token, text: str) -> Optional[str]:
    """The number written just before a unit token (``2`` in ``2 s``) on the same line, else None."""
    if tok.type != "NAME" or str(tok) not in ("s", "ms") or tok.start_pos is None:
        return None
    m = re.search(r"(\d+(?:\.\d+)?(?:[eE][+-]?\d+)?)[ \t]+$", text[max(0, tok.start_pos - 40):tok.start_pos])
    return m.group(1) if m else None


def _misspelt_keyword_hint(tok: Token, expected: set, text: str) -> Optional[str]:
    """'did you mean' for a misspelt keyword: the unexpected word itself, or the word before it
    (`eventualy[0, 3]` reads as a name followed by an unexpected '[')."""
    from .diagnostics import closest

    words = keywords()
    if tok.type == "NAME":
        wanted = [w for w, name in words.items() if name in expected]
        sug = closest(str(tok), wanted)
        if sug:
            return f"did you mean '{sug}'?"
    pos = getattr(tok, "start_pos", None)
    if pos is None:
        return None
    before = text[:pos].rstrip()
    i = len(before)
    while i > 0 and (before[i - 1].isalnum() or before[i - 1] == "_"):
        i -= 1
    word = before[i:]
    if word and word not in words and word[0].isalpha():
        sug = closest(word, words)
        if sug:
            return f"'{word}' is read as a name; did you mean the keyword '{sug}'?"
    return None


def _span(meta: Any) -> Span:
    if getattr(meta, "empty", True):
        return Span(1, 1, 1, 1)
    return Span(meta.line, meta.column, meta.end_line, meta.end_column)


def _number_text(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else repr(value)


def _join(a: Span, b: Span) -> Span:
    return Span(a.line, a.column, b.end_line, b.end_column)


@v_args(meta=True)
class _Builder(Transformer):
    """Lark tree -> AST nodes. Structural problems go to ``self.diag``."""

    def __init__(self, diag: Collector):
        super().__init__()
        self.diag = diag

    # -------------------------------------------------------------- expressions
    def number(self, meta, children):
        tok = children[0]
        return ast.Number(float(tok), _span_of_token(tok))

    def infinity(self, meta, children):
        return ast.Infinity(_span(meta))

    def name(self, meta, children):
        tok = children[0]
        return ast.Name(str(tok), _span_of_token(tok))

    def dt_ref(self, meta, children):  # `dt` read in an expression: the system's step, a constant
        return ast.Name("dt", _span(meta))

    def call(self, meta, children):
        tok = children[0]
        args = tuple(c for c in children[1:] if c is not None)
        return ast.Call(str(tok), args, _span(meta), _span_of_token(tok))

    def paren(self, meta, children):
        return children[0]

    def in_region(self, meta, children):
        tok = children[-1]
        return ast.InRegion(str(tok), _span(meta), _span_of_token(tok))

    def true(self, meta, children):
        return ast.BoolLiteral(True, _span(meta))

    def false(self, meta, children):
        return ast.BoolLiteral(False, _span(meta))

    def neg(self, meta, children):
        return ast.Unary("-", children[0], _span(meta))

    def unary(self, meta, children):  # unary plus: `+x` is x
        return children[0]

    def pow(self, meta, children):
        return ast.Binary("^", children[0], children[1], _span(meta))

    def arith_chain(self, meta, children):
        # a + b - c is (a + b) - c: left-associative, built in a loop (chains can be long). Every
        # partial result starts where the chain does (a parenthesis included).
        out, start = children[0], _span(meta)
        for (op, _), right in zip(children[1::2], children[2::2]):
            out = ast.Binary(op, out, right, _join(start, right.span))
        return out

    def compare(self, meta, children):
        left, (op, op_span), right = children
        return ast.Compare(op, left, right, _span(meta), op_span)

    def negation(self, meta, children):
        return ast.Not(children[1], _span(meta))

    def binary_logic(self, meta, children):
        left, (op, _), right = children
        return ast.Logic(_CANONICAL[op], left, right, _span(meta))

    def logic_chain(self, meta, children):
        out, start = children[0], _span(meta)
        for (op, _), right in zip(children[1::2], children[2::2]):
            out = ast.Logic(_CANONICAL[op], out, right, _join(start, right.span))
        return out

    def temporal1(self, meta, children):
        (op, op_span), interval, arg = children
        return ast.Temporal(_CANONICAL[op], interval, arg, _span(meta), op_span)

    def temporal2(self, meta, children):
        left, (op, op_span), interval, right = children
        return ast.Temporal2(_CANONICAL[op], interval, left, right, _span(meta), op_span)

    def _op(self, meta, children):
        tok = children[0]
        return (str(tok), _span_of_token(tok))

    implies_op = or_op = and_op = not_op = temporal1_op = temporal2_op = _op
    compare_op = add_op = mul_op = _op

    def interval(self, meta, children):
        lo, hi = children
        return ast.IntervalSyntax(lo, hi, _span(meta))

    def duration(self, meta, children):
        if not children:  # the keyword `inf` is filtered out of the tree
            return ast.Duration(float("inf"), "steps", _span(meta))
        tok = children[0]
        span = _span_of_token(tok)
        if tok.type == "INF":
            return ast.Duration(float("inf"), "steps", span)
        if tok.type == "DURATION":
            unit = "ms" if tok.endswith("ms") else "s"
            return ast.Duration(float(tok[: -len(unit)]), unit, span)
        return ast.Duration(float(tok), "steps", span)

    def range(self, meta, children):
        return ast.Range(children[0], children[1], _span(meta))

    # -------------------------------------------------------------- system
    def const_decl(self, meta, children):
        tok, value = children
        return ast.ConstDecl(str(tok), value, _span(meta), _span_of_token(tok))

    def bare_binding(self, meta, children):
        tok, value = children
        return ("bare_binding", ast.ConstDecl(str(tok), value, _span(meta), _span_of_token(tok)))

    def state_decl(self, meta, children):
        tok, space, init = children
        return ast.StateDecl(str(tok), space, init, _span(meta), _span_of_token(tok))

    def init_clause(self, meta, children):
        return children[0]

    def action_decl(self, meta, children):
        tok, bounds = children
        return ast.ActionDecl(str(tok), bounds, _span(meta), _span_of_token(tok))

    def let_decl(self, meta, children):
        tok, value = children
        return ast.LetDecl(str(tok), value, _span(meta), _span_of_token(tok))

    def dt_decl(self, meta, children):
        return ("dt", children[0])

    def ode_eq(self, meta, children):
        tok, _prime, value = children
        return ast.Equation(str(tok), value, _span(meta), _span_of_token(tok))

    def map_eq(self, meta, children):
        tok, value = children
        return ast.Equation(str(tok), value, _span(meta), _span_of_token(tok))

    def ode_block(self, meta, children):
        eqs = tuple(c for c in children if isinstance(c, ast.Equation))
        return ast.Dynamics("ode", eqs, _span(meta))

    def map_block(self, meta, children):
        eqs = tuple(c for c in children if isinstance(c, ast.Equation))
        return ast.Dynamics("map", eqs, _span(meta))

    def simulator_decl(self, meta, children):
        return ast.SimulatorDecl(str(children[0])[1:-1], _span(meta))

    def time_value(self, meta, children):
        tok = children[0]
        unit = "ms" if tok.endswith("ms") else "s"
        return ast.Duration(float(tok[: -len(unit)]), unit, _span_of_token(tok))

    def setting(self, meta, children):
        tok, value = children
        return ast.Setting(str(tok), value, _span(meta), _span_of_token(tok))

    train_setting = setting

    def integrator_args(self, meta, children):
        return tuple(c for c in children if c is not None)

    reward_args = integrator_args

    def integrator_decl(self, meta, children):
        tok, settings = children
        return ast.IntegratorDecl(str(tok), settings or (), _span(meta), _span_of_token(tok))

    def sep(self, meta, children):
        return ("sep", str(children[0]))

    def _fold_continuations(self, items: list, continue_head, attach=None) -> list:
        """Fold comma-continued items (``const a = 1, b = 2``, ``tolerances 30, 25``) into their head.

        ``continue_head(kind, head, payload)`` returns the items that replace ``head`` when the
        continuation belongs to it, else None (the continuation is then reported as misplaced).
        ``attach`` is tried the same way for an item that follows its head with no separator.
        """
        out: list = []
        last_sep: Optional[str] = None
        misplaced_name = False  # `dedline 30`: report the word, not also the number after it
        for item in items:
            if isinstance(item, tuple) and item[0] == "sep":
                last_sep = item[1]
                continue
            if isinstance(item, tuple) and item[0] in ("bare_binding", "bare_duration", "bare_name"):
                kind, payload = item
                folded = continue_head(kind, out[-1], payload) if last_sep == "," and out else None
                if folded is None and attach is not None and last_sep is None and out:
                    folded = attach(kind, out[-1], payload)
                if folded is not None:
                    out[-1:] = folded
                    misplaced_name = False
                elif not (misplaced_name and kind == "bare_duration" and last_sep is None):
                    self._misplaced(kind, payload)
                    misplaced_name = kind == "bare_name"
                last_sep = None
                continue
            out.append(item)
            last_sep = None
            misplaced_name = False
        return out

    def _misplaced(self, kind: str, payload: Any) -> None:
        if kind == "bare_binding":
            self.diag.add(
                "E119", f"'{payload.name} = ...' is not a declaration here", payload.span,
                hint=f"write `const {payload.name} = ...` or `let {payload.name} = ...`",
            )
        elif kind == "bare_duration":
            self.diag.add("E119", "a number on its own does not belong to any clause", payload.span,
                          hint="only `tolerances` takes a comma-separated list of numbers")
        else:
            from .diagnostics import closest

            clause = closest(payload[0], _TASK_CLAUSES)
            if clause:
                self.diag.add("E119", f"'{payload[0]}' is not a task clause", payload[1], hint=f"did you mean '{clause}'?")
            else:
                self.diag.add("E119", f"'{payload[0]}' on its own does not belong to any clause", payload[1],
                              hint="only `observe` takes a comma-separated list of names")

    def system(self, meta, children):
        tok = children[0]

        def continue_const(kind, head, payload):
            return [head, payload] if kind == "bare_binding" and isinstance(head, ast.ConstDecl) else None

        items = self._fold_continuations(list(children[1:]), continue_const)
        consts, states, actions, lets, dts, dyn, integ = [], [], [], [], [], [], []
        for it in items:
            if isinstance(it, ast.ConstDecl):
                consts.append(it)
            elif isinstance(it, ast.StateDecl):
                states.append(it)
            elif isinstance(it, ast.ActionDecl):
                actions.append(it)
            elif isinstance(it, ast.LetDecl):
                lets.append(it)
            elif isinstance(it, tuple) and it[0] == "dt":
                dts.append(it[1])
            elif isinstance(it, (ast.Dynamics, ast.SimulatorDecl)):
                dyn.append(it)
            elif isinstance(it, ast.IntegratorDecl):
                integ.append(it)
        return ast.System(str(tok), tuple(consts), tuple(states), tuple(actions), tuple(lets), tuple(dts),
                          tuple(dyn), tuple(integ), _span(meta), _span_of_token(tok))

    # -------------------------------------------------------------- regions
    def vector(self, meta, children):
        return ("vector", tuple(c for c in children if c is not None), _span(meta))

    def named_point(self, meta, children):
        return ("named", tuple(c for c in children if c is not None), _span(meta))

    def coord(self, meta, children):
        tok, value = children
        return ast.Coord(str(tok), value, _span(meta))

    def ball(self, meta, children):
        (kind, items, cspan), radius = children
        return ast.Ball(items, kind == "named", radius, _span(meta), cspan)

    def side(self, meta, children):
        tok, bounds = children
        return ast.BoxSide(str(tok), bounds, _span(meta))

    def box(self, meta, children):
        return ast.Box(tuple(c for c in children if c is not None), _span(meta))

    def region_decl(self, meta, children):
        tok, shape = children
        return ast.RegionDecl(str(tok), shape, _span(meta), _span_of_token(tok))

    def formula_decl(self, meta, children):
        tok, body = children
        return ast.FormulaDecl(str(tok), body, _span(meta), _span_of_token(tok))

    # -------------------------------------------------------------- tasks
    def _clause(keyword):
        def method(self, meta, children):
            value = children[0] if len(children) == 1 else tuple(children)
            return ast.Clause(keyword, value, _span(meta))
        return method

    asap_clause = _clause("asap")
    avoid_clause = _clause("avoid")
    deadline_clause = _clause("deadline")
    r_sat_clause = _clause("r_sat")

    def tolerances_clause(self, meta, children):
        return ast.Clause("tolerances", (children[0],), _span(meta))

    def bare_duration(self, meta, children):
        return ("bare_duration", children[0])

    def observe_item(self, meta, children):
        return (str(children[0]), _span_of_token(children[0]))

    def observe_clause(self, meta, children):
        return ast.Clause("observe", (children[0],), _span(meta))

    def bare_name(self, meta, children):
        return ("bare_name", children[0])

    def episode_clause(self, meta, children):
        return ast.Clause("episode", (children[0], children[1]), _span(meta))

    def task_init_clause(self, meta, children):
        return ast.Clause("init", children[0], _span(meta))

    def reward_kind(self, meta, children):
        return (str(children[0]), _span_of_token(children[0]))

    def reward_clause(self, meta, children):
        (kind, _), settings = children
        return ast.Clause("reward", ast.RewardSyntax(kind, settings or (), _span(meta)), _span(meta))

    def train_block(self, meta, children):
        settings = tuple(c for c in children if isinstance(c, ast.Setting))
        return ast.Clause("train", settings, _span(meta))

    def task_decl(self, meta, children):
        tok = children[0]

        def continue_clause(kind, head, payload):
            # `tolerances 30, 25` and `observe state, time` continue with comma-separated items.
            want = {"bare_duration": "tolerances", "bare_name": "observe"}.get(kind)
            if not (isinstance(head, ast.Clause) and head.keyword == want):
                return None
            end = payload[1] if isinstance(payload, tuple) else payload.span
            return [ast.Clause(head.keyword, head.value + (payload,), _join(head.span, end))]

        merged = self._fold_continuations(list(children[1:]), continue_clause, self._spaced_unit)
        clauses = tuple(c for c in merged if isinstance(c, ast.Clause))
        return ast.TaskDecl(str(tok), clauses, _span(meta), _span_of_token(tok))

    def _spaced_unit(self, kind, head, payload):
        """``deadline 15 s``: a unit written apart from its number. One error at the unit, and the
        time read as meant (15 s), so that nothing is reported for a deadline of 15 steps."""
        if kind != "bare_name" or payload[0] not in ("s", "ms") or not isinstance(head, ast.Clause):
            return None
        value = head.value
        last = value[-1] if isinstance(value, tuple) and value else value
        if not isinstance(last, ast.Duration) or last.unit != "steps" or last.is_inf:
            return None
        unit, span = payload
        if span.line != last.span.end_line:
            return None
        self.diag.add("E001", f"write `{_number_text(last.value)}{unit}`: a unit goes right after its number, "
                      "with no space", span)
        fixed = ast.Duration(last.value, unit, _join(last.span, span))
        value = value[:-1] + (fixed,) if isinstance(value, tuple) else fixed
        return [ast.Clause(head.keyword, value, _join(head.span, span))]

    def start(self, meta, children):
        systems = tuple(c for c in children if isinstance(c, ast.System))
        regions = tuple(c for c in children if isinstance(c, ast.RegionDecl))
        formulas = tuple(c for c in children if isinstance(c, ast.FormulaDecl))
        tasks = tuple(c for c in children if isinstance(c, ast.TaskDecl))
        return ast.Module(self.diag.file, systems, regions, formulas, tasks)


# Parse-tree nodes that nest an expression one level deeper.
_NESTING = frozenset({"paren", "call", "neg", "unary", "pow", "negation", "temporal1", "temporal2",
                      "binary_logic", "compare", "arith_chain", "logic_chain"})


def _too_deep(tree: lark.Tree) -> Optional[Span]:
    """Where the parse tree first nests more than ``LIMITS.nesting`` expression levels (None if nowhere),
    found without recursion: the tree is as deep as the user made it."""
    stack = [(tree, 0)]
    while stack:
        node, depth = stack.pop()
        if node.data in _NESTING:
            depth += 1
            if depth > LIMITS.nesting:
                return _span(node.meta)
        for child in node.children:
            if isinstance(child, lark.Tree):
                stack.append((child, depth))
    return None


def parse(text: str, file: str = "<string>") -> tuple[ast.Module, list[Diagnostic]]:
    """Parse ``text`` into a module.

    A syntax error raises :class:`SpecError` (only the first one: later ones are unreliable
    after the parser has lost its way). Structural problems that the parse survives are returned
    as diagnostics for the checker to report with its own.
    """
    diag = Collector(file)
    try:
        tree = _lark().parse(text)
    except lark.exceptions.LarkError as err:
        raise SpecError([_syntax_diagnostic(err, text, file)], text) from None
    except RecursionError:
        raise SpecError([make("E001", "the text nests too deeply to parse", Span(1, 1, 1, 2), file)], text) from None
    too_deep = _too_deep(tree)
    if too_deep is not None:
        raise SpecError([make("E001", f"the expression nests more than {LIMITS.nesting} levels deep here (parentheses, "
                              "function calls, `not`, `-` and temporal operators)", too_deep, file,
                              hint="split it into named parts with `let` or `formula`")], text)
    try:
        module = _Builder(diag).transform(tree)
    except lark.exceptions.VisitError as err:  # a builder bug must still not reach the user raw
        raise SpecError([make("E001", f"the text could not be read: {err.orig_exc}", Span(1, 1, 1, 2), file)], text) from None
    except RecursionError:
        raise SpecError([make("E001", "the text nests too deeply to parse", Span(1, 1, 1, 2), file)], text) from None
    return module, diag.items
