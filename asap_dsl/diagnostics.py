"""Diagnostics: positioned errors and warnings, their stable codes, and how they are printed.

Every problem the front end finds is a :class:`Diagnostic` with a stable code (``E101``) and a
name (``unknown-name``); :data:`RULES` is the single list of them, and ``docs/language.md``
documents each. A :class:`SpecError` carries every diagnostic of a file at once.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Optional


@dataclass(frozen=True, order=True)
class Span:
    """A source range, 1-based lines and columns; ``end_column`` is exclusive."""

    line: int = 1
    column: int = 1
    end_line: int = 1
    end_column: int = 1

    def __str__(self) -> str:
        return f"{self.line}:{self.column}"


@dataclass(frozen=True)
class Rule:
    code: str
    name: str
    severity: str  # "error" or "warning"
    summary: str


# The single list of diagnostic codes. Codes are stable: never renumber, only append.
RULES: dict[str, Rule] = {
    r.code: r
    for r in [
        Rule("E001", "syntax-error", "error", "The text does not follow the grammar."),
        Rule("E002", "unreadable-file", "error", "The file is missing, a directory, not a regular file, larger than the limit (10 MB; `asapc --max-spec-size MB`), not UTF-8 text, or empty."),
        Rule("E101", "unknown-name", "error", "A name that is not declared (with the closest declared name)."),
        Rule("E102", "duplicate-name", "error", "A name declared twice, or a reserved constant redeclared."),
        Rule("E103", "wrong-kind", "error", "A name used as something it is not (a region as a number, a state as a formula, ...)."),
        Rule("E104", "dimension-mismatch", "error", "A ball centre whose length differs from the number of states, or a function with the wrong number of arguments."),
        Rule("E105", "reversed-interval", "error", "An interval or range whose lower bound exceeds its upper bound."),
        Rule("E106", "not-whole-steps", "error", "A time in seconds that is not a whole number of steps of dt, or a step count that is not a whole number."),
        Rule("E107", "future-in-causal", "error", "A future operator in `asap` or `avoid`, which must be causal."),
        Rule("E108", "init-outside-space", "error", "An `init` box that is not inside the state space."),
        Rule("E109", "missing-equation", "error", "A state without an equation in `ode` or `map`."),
        Rule("E110", "duplicate-equation", "error", "A state with two equations, or an equation for a name that is not a state."),
        Rule("E111", "exact-nonlinear", "error", "`integrator exact` on dynamics that are not linear in states and actions."),
        Rule("E112", "tolerance-above-deadline", "error", "A tolerance or episode length above the deadline."),
        Rule("E113", "goal-outside-space", "error", "The `asap` region lies entirely outside the state space: unreachable."),
        Rule("E114", "missing-declaration", "error", "A required part is missing (system, dt, dynamics, state, asap, deadline, an action for a task to control, ...)."),
        Rule("E115", "equality-comparison", "error", "`==` or `!=` between real signals, which robustness cannot measure."),
        Rule("E116", "type-mismatch", "error", "A number where a condition is expected, or the other way round."),
        Rule("E117", "invalid-value", "error", "A value out of its domain (non-positive dt or radius, empty range, unknown setting, ...)."),
        Rule("E118", "unknown-function", "error", "A call to a function the language does not have."),
        Rule("E119", "misplaced-declaration", "error", "A declaration in the wrong place (an integrator without an ODE, a bare `x = 1`, ...)."),
        Rule("E120", "cyclic-definition", "error", "A constant, let or formula defined in terms of itself."),
        Rule("E121", "not-constant", "error", "An expression that must be a constant but reads a state, action or let."),
        Rule("E122", "init-not-sampleable", "error", "An `init` range (given, or the state space by default) that is infinite or too wide to draw states from uniformly."),
        Rule("E123", "init-inside-avoid", "error", "Every initial state (512 drawn from the `init` box) already satisfies `avoid`: no episode can start."),
        Rule("E124", "outside-domain", "error", "An operation whose argument is outside its domain for every state: sqrt or log of a negative number, asin/acos beyond ±1, a division by zero, a negative base to a fractional power."),
        Rule("E125", "asap-never-holds", "error", "`asap` asks to be in two regions at once that do not overlap (in every branch of an `or`): no episode can fulfil it."),
        Rule("W201", "regions-overlap", "warning", "The `asap` region overlaps the `avoid` region: the target is partly unsafe."),
        Rule("W202", "unused-name", "warning", "A constant, let, region or formula that nothing uses."),
        Rule("W203", "horizon-beyond-deadline", "warning", "A formula looks further into the past than the deadline allows any trace to be long."),
        Rule("W204", "r-sat-below-bound", "warning", "A numeric `r_sat` below the theorem's bound rho_max + (rho_max - rho_min) * k_max."),
        Rule("W206", "goal-partly-outside-space", "warning", "Part of the `asap` region lies outside the state space."),
        Rule("W207", "unbounded-robustness", "warning", "Robustness bounds are infinite, so `r_sat auto` cannot apply the theorem."),
        Rule("W209", "may-leave-domain", "warning", "An operation whose argument may leave its domain for some states of the state space (NaN or infinity there, which ends the episode as `non_finite`)."),
        Rule("W208", "deadline-infeasible", "warning", "(lint --deep) Some sampled initial states cannot reach the goal within the deadline."),
    ]
}


@dataclass(frozen=True)
class Diagnostic:
    """One problem in a spec, positioned in its file."""

    code: str
    severity: str
    message: str
    file: str
    line: int
    column: int
    end_line: int
    end_column: int
    hint: Optional[str] = None

    @property
    def name(self) -> str:
        return RULES[self.code].name

    @property
    def is_error(self) -> bool:
        return self.severity == "error"

    def as_dict(self) -> dict:
        return {
            "code": self.code,
            "name": self.name,
            "severity": self.severity,
            "message": self.message,
            "hint": self.hint,
            "file": self.file,
            "line": self.line,
            "column": self.column,
            "end_line": self.end_line,
            "end_column": self.end_column,
        }


MESSAGE = 500  # characters of a message or hint (a name of 2 MB quoted in one is cut)


def shorten(text: str, limit: int = MESSAGE) -> str:
    """``text`` cut in the middle to about ``limit`` characters, saying how much was left out."""
    if len(text) <= limit:
        return text
    head, tail = text[: limit * 2 // 3], text[-(limit // 4):]
    return f"{head} …({len(text) - len(head) - len(tail):,} characters)… {tail}"


def make(code: str, message: str, span: Span, file: str, hint: Optional[str] = None) -> Diagnostic:
    rule = RULES[code]
    return Diagnostic(code, rule.severity, shorten(message), file, span.line, span.column, span.end_line,
                      span.end_column, None if hint is None else shorten(hint))


@dataclass
class Collector:
    """Gathers diagnostics for one file; the checker reports into it and never stops early."""

    file: str
    items: list[Diagnostic] = field(default_factory=list)

    def add(self, code: str, message: str, span: Span, hint: Optional[str] = None) -> None:
        self.items.append(make(code, message, span, self.file, hint))

    @property
    def has_errors(self) -> bool:
        return any(d.is_error for d in self.items)

    def sorted(self) -> list[Diagnostic]:
        return sort(self.items)


def sort(diagnostics: Iterable[Diagnostic]) -> list[Diagnostic]:
    unique = list(dict.fromkeys(diagnostics))
    return sorted(unique, key=lambda d: (d.file, d.line, d.column, d.code, d.message))


_CONTROL = {c: f"\\x{c:02x}" for c in list(range(0x20)) + [0x7f] if c != 0x09}
_CONTROL.update({c: f"\\u{c:04x}" for c in range(0x80, 0xa0)})
EXCERPT = 200  # characters of a source line shown around the problem


def span_text(lines: list[str], span: Span) -> str:
    """The source text of ``span`` (``lines`` are the file's lines), on one line."""
    if span.line < 1 or span.line > len(lines):
        return ""
    if span.end_line == span.line:
        return lines[span.line - 1][span.column - 1: span.end_column - 1]
    first = lines[span.line - 1][span.column - 1:]
    middle = lines[span.line: span.end_line - 1]
    last = lines[span.end_line - 1][: span.end_column - 1] if span.end_line <= len(lines) else ""
    return " ".join(x.strip() for x in [first, *middle, last])


def printable(text: str) -> str:
    """``text`` safe for a terminal: control characters (ESC, BEL, ...) as visible escapes."""
    return text.translate(_CONTROL)


def format_diagnostic(d: Diagnostic, source: Optional[str], lines: Optional[list[str]] = None) -> str:
    """``file:line:col: error E101 unknown-name: message``, then the line and a caret.

    ``lines`` are ``source.splitlines()`` when the caller formats many diagnostics of one file
    (split once, not once per diagnostic). Control characters are shown escaped, and a long line
    is cut to :data:`EXCERPT` characters around the problem.
    """
    where = f"{d.file}:{d.line}:{d.column}" if d.line >= 1 else d.file  # line 0: the file as a whole
    out = [printable(f"{where}: {d.severity} {d.code} {d.name}: {d.message}")]
    if source is not None and d.line >= 1:
        text_lines = lines if lines is not None else source.splitlines()
        if d.line <= len(text_lines):
            text = text_lines[d.line - 1].expandtabs(1)
            width = 1
            if d.end_line == d.line and d.end_column > d.column:
                width = d.end_column - d.column
            width = max(1, min(width, len(text) - d.column + 1))
            start = max(0, min(d.column - 1 - EXCERPT // 2, len(text) - EXCERPT))
            cut = text[start:start + EXCERPT]
            before = printable(text[start:d.column - 1])
            marked = printable(text[d.column - 1:d.column - 1 + width])[: max(1, EXCERPT - len(before))]
            left = "…" if start > 0 else ""
            right = "…" if start + EXCERPT < len(text) else ""
            out.append(f"  {d.line:>4} | {left}{printable(cut)}{right}")
            out.append(f"       | {' ' * (len(left) + len(before))}{'^' * max(1, len(marked))}")
    if d.hint:
        out.append(printable(f"       = hint: {d.hint}"))
    return "\n".join(out)


SHOWN = 100  # diagnostics printed in full by default (`asapc lint --max-diagnostics N`; 0: all)


def format_report(diagnostics: Iterable[Diagnostic], sources: dict[str, Optional[str]],
                  limit: Optional[int] = SHOWN) -> str:
    """Every diagnostic formatted, or the first ``limit`` of them (errors before warnings) and a
    line counting the rest by code: 10,000 unused regions are one line, not a megabyte."""
    diagnostics = list(diagnostics)
    shown = diagnostics
    if limit and len(diagnostics) > limit:
        keep = set(map(id, sorted(diagnostics, key=lambda d: not d.is_error)[:limit]))
        shown = [d for d in diagnostics if id(d) in keep]
    split = {f: (s.splitlines() if s is not None else None) for f, s in sources.items()}
    out = [format_diagnostic(d, sources.get(d.file), split.get(d.file)) for d in shown]
    if len(shown) < len(diagnostics):
        kept = set(map(id, shown))
        rest: dict[str, int] = {}
        for d in diagnostics:
            if id(d) not in kept:
                rest[d.code] = rest.get(d.code, 0) + 1
        counts = ", ".join(f"{n:,} {code}" for code, n in sorted(rest.items()))
        out.append(f"... and {len(diagnostics) - len(shown):,} more ({counts}); "
                   "`asapc lint --max-diagnostics 0` prints every one")
    return "\n".join(out)


class SpecError(Exception):
    """A spec has errors. ``.diagnostics`` lists all of them (and its warnings), sorted."""

    def __init__(self, diagnostics: list[Diagnostic], source: Optional[str] = None):
        self.diagnostics = sort(diagnostics)
        self.source = source
        super().__init__(self.report())

    @property
    def errors(self) -> list[Diagnostic]:
        return [d for d in self.diagnostics if d.is_error]

    def report(self) -> str:
        files = {d.file for d in self.diagnostics}
        return format_report(self.diagnostics, {f: self.source for f in files})

    def __str__(self) -> str:
        return self.report()


def closest(name: str, candidates: Iterable[str]) -> Optional[str]:
    """The most similar candidate, if any is close enough to be a plausible typo."""
    import difflib

    matches = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.6)
    return matches[0] if matches else None
