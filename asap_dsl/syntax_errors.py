"""Lark's syntax errors in plain words: one positioned E001 diagnostic, saying what was found
and what the grammar expected there in the language's own terms (never Lark's terminal names),
with a hint for the usual slips (a reserved word as a name, a misspelt keyword, a unit apart from
its number, a missing closing bracket)."""

from __future__ import annotations

import functools
import re
from typing import Optional

import lark
from lark import Token

from .diagnostics import Diagnostic, Span, make
from .lark_parser import get_parser, keywords, token_span

# Plain words for the grammar's named terminals (punctuation and keywords print as themselves).
_TERMINAL_WORDS = {
    "NAME": "a name",
    "NUMBER": "a number",
    "DURATION": "a time such as 3s or 500ms",
    "STRING": 'a string in double quotes',
    "PRIME": "a prime (')",
    }


@functools.lru_cache(maxsize=None)
def _terminal_patterns() -> dict[str, str]:
    """Terminal name -> how to show it to a user."""
    out = {}
    for t in get_parser().terminals:
        if t.name in _TERMINAL_WORDS:
            out[t.name] = _TERMINAL_WORDS[t.name]
        elif isinstance(t.pattern, lark.lexer.PatternStr):
            out[t.name] = f"'{t.pattern.value}'"
        else:
            out[t.name] = t.name.lower()
    return out


def _describe_expected(names: set[str], end: str) -> str:
    words = {**_terminal_patterns(), "$END": end}
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


def _describe_token(tok: Token, end: str) -> str:
    if tok.type == "$END":
        return end
    if tok.type == "NAME":
        return f"name '{tok}'"
    if tok.type in ("NUMBER", "DURATION"):
        return f"number {tok}"
    if tok.type == "STRING":
        return f"string {tok}"
    if tok.isidentifier():
        return f"keyword '{tok}'"
    return f"'{tok}'"


def syntax_diagnostic(err: lark.exceptions.LarkError, text: str, file: str, end: str = "the end of the file") -> Diagnostic:
    """The E001 diagnostic of Lark's ``err`` on ``text`` (of ``file``); ``end`` names the end of
    the text where it is found there (a file's, or a flag's)."""
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
            span = token_span(tok)
        spaced = _spaced_unit_before(tok, text)
        if spaced is not None:  # `episode 2 s .. 15s`: the unit apart from its number
            return make("E001", f"write `{spaced}{tok}`: a unit goes right after its number, with no space", span, file)
        expected = _describe_expected(set(err.expected), end)
        message = f"unexpected {_describe_token(tok, end)}" + (f"; {expected}" if expected else "")
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
        return make("E001", f"unexpected {end}", Span(line, col, line, col + 1), file, "a '}', ')' or ']' may be missing")
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
