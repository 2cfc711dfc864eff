"""Source text to AST: the Lark transformer that builds :mod:`asap_dsl.ast` nodes, and the
entry points :func:`parse` (a file) and :func:`parse_reward` (a reward on its own).

The grammar lives in ``grammar/asap.lark``; the parser is :mod:`asap_dsl.lark_parser`'s, built
once per process; Lark's errors are put in plain words by :mod:`asap_dsl.syntax_errors`.
"""

from __future__ import annotations

from typing import Any, Optional

import lark
from lark import Transformer, v_args

from . import ast
from .diagnostics import Collector, Diagnostic, Span, SpecError, make
from .lark_parser import get_parser, keywords, token_span
from .limits import LIMITS
from .syntax_errors import syntax_diagnostic

__all__ = ["get_parser", "keywords", "parse", "parse_reward"]

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
        return ast.Number(float(tok), token_span(tok))

    def infinity(self, meta, children):
        return ast.Infinity(_span(meta))

    def name(self, meta, children):
        tok = children[0]
        return ast.Name(str(tok), token_span(tok))

    def dt_ref(self, meta, children):  # `dt` read in an expression: the system's step, a constant
        return ast.Name("dt", _span(meta))

    def call(self, meta, children):
        tok = children[0]
        args = tuple(c for c in children[1:] if c is not None)
        return ast.Call(str(tok), args, _span(meta), token_span(tok))

    def paren(self, meta, children):
        return children[0]

    def in_region(self, meta, children):
        tok = children[-1]
        return ast.InRegion(str(tok), _span(meta), token_span(tok))

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

    def conditional(self, meta, children):
        test, then_, else_ = children
        return ast.Conditional(test, then_, else_, _span(meta))

    def temporal1(self, meta, children):
        (op, op_span), interval, arg = children
        return ast.Temporal(_CANONICAL[op], interval, arg, _span(meta), op_span)

    def temporal2(self, meta, children):
        left, (op, op_span), interval, right = children
        return ast.Temporal2(_CANONICAL[op], interval, left, right, _span(meta), op_span)

    def _op(self, meta, children):
        tok = children[0]
        return (str(tok), token_span(tok))

    implies_op = or_op = and_op = not_op = temporal1_op = temporal2_op = _op
    compare_op = add_op = mul_op = _op

    def interval(self, meta, children):
        lo, hi = children
        return ast.IntervalSyntax(lo, hi, _span(meta))

    def duration(self, meta, children):
        if not children:  # the keyword `inf` is filtered out of the tree
            return ast.Duration(float("inf"), "steps", _span(meta))
        tok = children[0]
        span = token_span(tok)
        if tok.type == "INF":
            return ast.Duration(float("inf"), "steps", span)
        if tok.type == "DURATION":
            unit = "ms" if tok.endswith("ms") else "s"
            return ast.Duration(float(tok[: -len(unit)]), unit, span)
        if len(children) == 2:  # `200 steps`: the unit is the default one, written out
            span = _join(span, token_span(children[1]))
        return ast.Duration(float(tok), "steps", span)

    def range(self, meta, children):
        return ast.Range(children[0], children[1], _span(meta))

    # -------------------------------------------------------------- declarations
    def _named(cls):
        """A declaration ``NAME ...``: ``cls(name, *the rest, span, name_span)``."""
        def method(self, meta, children):
            tok, *rest = children
            return cls(str(tok), *rest, _span(meta), token_span(tok))
        return method

    const_decl = _named(ast.ConstDecl)
    state_decl = _named(ast.StateDecl)
    action_decl = _named(ast.ActionDecl)
    let_decl = _named(ast.LetDecl)
    map_eq = _named(ast.Equation)
    setting = train_setting = _named(ast.Setting)
    region_decl = _named(ast.RegionDecl)
    formula_decl = _named(ast.FormulaDecl)

    # -------------------------------------------------------------- system
    def bare_binding(self, meta, children):
        tok, value = children
        return ("bare_binding", ast.ConstDecl(str(tok), value, _span(meta), token_span(tok)))

    def init_clause(self, meta, children):
        return children[0]

    def dt_decl(self, meta, children):
        return ("dt", children[0])

    def ode_eq(self, meta, children):
        tok, _prime, value = children
        return ast.Equation(str(tok), value, _span(meta), token_span(tok))

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
        return ast.Duration(float(tok[: -len(unit)]), unit, token_span(tok))

    def integrator_args(self, meta, children):
        return tuple(c for c in children if c is not None)

    reward_args = integrator_args

    def integrator_decl(self, meta, children):
        tok, settings = children
        return ast.IntegratorDecl(str(tok), settings or (), _span(meta), token_span(tok))

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
            if isinstance(item, tuple) and item[0] in ("bare_binding", "bare_duration", "bare_name", "bare_observe"):
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
        elif kind == "bare_observe":
            self.diag.add("E119", f"'{payload.name} = {payload.value}' does not belong to any clause", payload.span,
                          hint=f"it is a setting of `observe`: write `observe state, {payload.name} = {payload.value}`")
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
                          tuple(dyn), tuple(integ), _span(meta), token_span(tok))

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
        return (str(children[0]), token_span(children[0]))

    def observe_clause(self, meta, children):
        return ast.Clause("observe", (children[0],), _span(meta))

    def bare_name(self, meta, children):
        return ("bare_name", children[0])

    def observe_choice(self, meta, children):
        return str(children[0])

    def observe_setting(self, meta, children):  # `scaling = init`, its value a plain name
        tok, value = children
        return ast.Setting(str(tok), value, _span(meta), token_span(tok))

    def bare_observe(self, meta, children):
        return ("bare_observe", children[0])

    def episode_clause(self, meta, children):
        return ast.Clause("episode", (children[0], children[1]), _span(meta))

    def task_init_clause(self, meta, children):
        return ast.Clause("init", children[0], _span(meta))

    def reward_kind(self, meta, children):
        return (str(children[0]), token_span(children[0]))

    def reward(self, meta, children):
        (kind, _), settings = children
        return ast.RewardSyntax(kind, settings or (), _span(meta))

    def reward_clause(self, meta, children):  # the reward's span is the clause's, keyword included
        syn = children[0]
        return ast.Clause("reward", ast.RewardSyntax(syn.kind, syn.settings, _span(meta)), _span(meta))

    def train_list(self, meta, children):
        return ast.ListValue(tuple(c for c in children if c is not None), _span(meta))

    def train_entry(self, meta, children):
        tok, value = children
        return (str(tok), value, token_span(tok))

    def train_object(self, meta, children):
        return ast.ObjectValue(tuple(c for c in children if c is not None), _span(meta))

    def train_block(self, meta, children):
        settings = tuple(c for c in children if isinstance(c, ast.Setting))
        return ast.Clause("train", settings, _span(meta))

    def task_decl(self, meta, children):
        tok = children[0]

        def continue_clause(kind, head, payload):
            # `tolerances 30, 25` and `observe state, time` continue with comma-separated items.
            want = {"bare_duration": "tolerances", "bare_name": "observe", "bare_observe": "observe"}.get(kind)
            if not (isinstance(head, ast.Clause) and head.keyword == want):
                return None
            end = payload[1] if isinstance(payload, tuple) else payload.span
            return [ast.Clause(head.keyword, head.value + (payload,), _join(head.span, end))]

        merged = self._fold_continuations(list(children[1:]), continue_clause, self._spaced_unit)
        clauses = tuple(c for c in merged if isinstance(c, ast.Clause))
        return ast.TaskDecl(str(tok), clauses, _span(meta), token_span(tok))

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
                      "binary_logic", "compare", "arith_chain", "logic_chain", "conditional"})


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
    return _build(text, file, "start", "the end of the file")


def parse_reward(text: str, file: str = "--reward") -> ast.RewardSyntax:
    """Parse a reward written on its own as the ``reward`` clause writes it (``asap``,
    ``rho(window = 5)``, ``distance(lambda_t = 2, base = 1)``), by the grammar's own rule.
    A syntax error raises :class:`SpecError`, as :func:`parse` does."""
    syn, _ = _build(text, file, "reward", "end of the reward")
    return syn


def _build(text: str, file: str, start: str, end: str) -> tuple[Any, list[Diagnostic]]:
    """The AST of ``text`` parsed from the rule ``start``, and the structural diagnostics."""
    diag = Collector(file)
    try:
        tree = get_parser().parse(text, start=start)
    except lark.exceptions.LarkError as err:
        raise SpecError([syntax_diagnostic(err, text, file, end)], text) from None
    except RecursionError:
        raise SpecError([make("E001", "the text nests too deeply to parse", Span(1, 1, 1, 2), file)], text) from None
    too_deep = _too_deep(tree)
    if too_deep is not None:
        raise SpecError([make("E001", f"the expression nests more than {LIMITS.nesting} levels deep here (parentheses, "
                              "function calls, `not`, `-` and temporal operators)", too_deep, file,
                              hint="split it into named parts with `let` or `formula`")], text)
    try:
        built = _Builder(diag).transform(tree)
    except lark.exceptions.VisitError as err:  # a builder bug must still not reach the user raw
        raise SpecError([make("E001", f"the text could not be read: {err.orig_exc}", Span(1, 1, 1, 2), file)], text) from None
    except RecursionError:
        raise SpecError([make("E001", "the text nests too deeply to parse", Span(1, 1, 1, 2), file)], text) from None
    return built, diag.items
