"""The Lark LALR parser of the grammar (``grammar/asap.lark``, shipped inside the package as
``asap_dsl/grammar/asap.lark``), built once per process, and what the grammar reserves.

Its start symbols: ``start`` (a whole file) and ``reward`` (a reward on its own, as the
``reward`` clause writes it: what ``asapc train --reward`` takes).
"""

from __future__ import annotations

import functools
from importlib import resources
from pathlib import Path

import lark
from lark import Token

from .diagnostics import Span

START_SYMBOLS = ("start", "reward")


def grammar_text() -> str:
    """The grammar's text."""
    # Installed: the grammar ships inside the package. From a source checkout: grammar/asap.lark.
    try:
        return resources.files("asap_dsl").joinpath("grammar/asap.lark").read_text(encoding="utf-8")
    except (FileNotFoundError, ModuleNotFoundError, NotADirectoryError):
        here = Path(__file__).resolve().parent.parent / "grammar" / "asap.lark"
        return here.read_text(encoding="utf-8")


@functools.lru_cache(maxsize=None)
def keywords() -> dict[str, str]:
    """Reserved words of the language (every keyword of the grammar) -> their terminal names."""
    return {t.pattern.value: t.name for t in get_parser().terminals
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
def get_parser() -> lark.Lark:
    """The parser (built on the first call; later calls return it)."""
    # cache=True keeps the built LALR tables on disk, keyed by the grammar and the options: a cold
    # `asapc lint` then loads them instead of rebuilding them.
    return lark.Lark(grammar_text(), parser="lalr", propagate_positions=True, maybe_placeholders=True,
                     lexer_callbacks={"NAME": _reserve_keywords}, cache=True, start=list(START_SYMBOLS))


def token_span(tok: Token) -> Span:
    """Where a token stands in the text."""
    line = tok.line or 1
    col = tok.column or 1
    end_line = tok.end_line or line
    end_col = tok.end_column or col + max(1, len(tok))
    return Span(line, col, end_line, end_col)
