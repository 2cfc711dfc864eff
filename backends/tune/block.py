"""A task's ``train { ... }`` block as text: the winning settings merged into the task's own block,
written as the language reads it, and put into the spec file in place of the old one.

Writing keeps every other byte of the file (comments, spacing, ``\\r\\n`` line ends, a byte-order
mark): only the task's train block is replaced, or a new one is added as the task's last clause,
indented as its clauses are. The new text is checked by the language before the file is replaced,
atomically (a temporary beside it, renamed over it, its permissions kept).
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

__all__ = ["BlockError", "format_block", "merged_block", "replaced_source", "setting_text", "write_block"]

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_LINE = 100  # a block longer than this goes on several lines
_RUN_FIRST = ("algo", "steps", "seed", "preset", "n_envs", "eval_episodes")
# Spellings of one setting: a block's other spelling goes when the search sets this one.
_SAME = {"target_entropy_per_action": ("target_entropy",), "action_noise": ()}


class BlockError(ValueError):
    """The block cannot be written into the spec (one sentence)."""


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise BlockError(f"{v} cannot be written in a train block")
        if v.is_integer() and abs(v) < 1e15:
            return str(int(v)) if abs(v) >= 1 or v == 0 else repr(v)
        return format(v, ".6g")
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{k}: {_value(x)}" for k, x in v.items()) + "}"
    raise BlockError(f"{v!r} cannot be written in a train block")


def setting_text(name: str, value: Any) -> str:
    """``name = value`` as a train block writes it."""
    if name == "algo" and isinstance(value, str) and _NAME.match(value):
        return f"algo = {value}"  # as the specs write it
    return f"{name} = {_value(value)}"


def format_block(settings: Mapping[str, Any], indent: str = "  ", newline: str = "\n") -> str:
    """``train { a = 1, b = [64, 64] }`` on one line when it is short, else one setting per line
    (the clause's ``indent`` before the closing brace, two more spaces before each setting)."""
    items = [setting_text(k, v) for k, v in settings.items()]
    line = "train { " + ", ".join(items) + " }" if items else "train { }"
    if len(indent) + len(line) <= _LINE:
        return line
    inner = indent + "  "
    return "train {" + newline + "".join(f"{inner}{s}{newline}" for s in items) + indent + "}"


def merged_block(block: Mapping[str, Any], winner: Mapping[str, Any], algo: Optional[str] = None,
                 keep: Optional[Sequence[str]] = None) -> dict[str, Any]:
    """The task's block with the winning settings: each in the place the block has it (or inside
    its ``policy_kwargs``), the others after; ``algo`` when the tuning trained another than the
    block's (given only then); the block's other spelling of a searched setting left out. ``keep``: the block's
    hyperparameters to keep (default all; those the tuned algorithm does not take are dropped by
    the caller)."""
    out: dict[str, Any] = {}
    drop = {o for k in winner for o in _SAME.get(k, ())}
    nested = dict(block.get("policy_kwargs") or {}) if isinstance(block.get("policy_kwargs"), Mapping) else None
    for k, v in block.items():
        if k in drop or (keep is not None and k not in keep and k not in _RUN_FIRST and k != "policy_kwargs"):
            continue
        out[k] = winner.get(k, v) if k != "policy_kwargs" else v
    if nested is not None:
        out["policy_kwargs"] = {k: winner.get(k, v) for k, v in nested.items() if k not in drop}
        placed = set(nested)
    else:
        placed = set()
    if algo is not None:  # the caller's choice: the tuning trained another algorithm than the block's
        out["algo"] = algo
    for k, v in winner.items():
        if k not in out and k not in placed:
            out[k] = v
    head = {k: out.pop(k) for k in _RUN_FIRST if k in out}
    return {**head, **out}


# ---------------------------------------------------------------------------------- the file
def _offsets(raw: str) -> list[int]:
    """For each character of the text with its line ends made ``\\n`` (as the language reads it),
    its offset in ``raw``; one more entry for the end."""
    out: list[int] = []
    i = 0
    while i < len(raw):
        out.append(i)
        i += 2 if raw.startswith("\r\n", i) else 1
    out.append(len(raw))
    return out


def _at(text: str, line: int, column: int) -> int:
    """The offset of a 1-based line and column of ``text``."""
    start = 0
    for _ in range(line - 1):
        start = text.index("\n", start) + 1
    return start + column - 1


def _task_spans(text: str, task: str):
    from asap_dsl import parser

    module, _ = parser.parse(text, "<spec>")
    for decl in module.tasks:
        if decl.name == task:
            return decl
    raise BlockError(f"the spec has no task named '{task}'")


def _newline(raw: str) -> str:
    return "\r\n" if "\r\n" in raw else "\n"


def replaced_source(raw: str, task: str, settings: Mapping[str, Any]) -> str:
    """``raw`` (the file's text, line ends as they are) with ``task``'s train block made ``settings``."""
    from asap_dsl.program import normalise_newlines

    text = normalise_newlines(raw)
    offsets = _offsets(raw) if "\r" in raw else None
    decl = _task_spans(text, task)
    trains = [c for c in decl.clauses if c.keyword == "train"]
    clauses = [c for c in decl.clauses if c.keyword != "train"] or list(decl.clauses)
    nl = _newline(raw)

    def raw_at(i: int) -> int:
        return offsets[i] if offsets is not None else i

    if trains:
        old = trains[-1].span
        start, end = _at(text, old.line, old.column), _at(text, old.end_line, old.end_column)
        indent = text[text.rfind("\n", 0, start) + 1:start]
        indent = indent if not indent.strip() else "  "
        new = format_block(settings, indent, nl)
        return raw[:raw_at(start)] + new + raw[raw_at(end):]
    # A new block: the task's last clause line, then the block on a line of its own, as indented.
    first = clauses[0].span if clauses else decl.span
    indent = " " * (first.column - 1) if clauses else "  "
    close = _at(text, decl.span.end_line, decl.span.end_column) - 1  # the task's "}"
    line_start = text.rfind("\n", 0, close) + 1
    new = format_block(settings, indent, nl)
    if not text[line_start:close].strip():  # "}" on a line of its own: the block goes on the line before it
        return raw[:raw_at(line_start)] + indent + new + nl + raw[raw_at(line_start):]
    last = len(text[:close].rstrip())  # task t { ... } on one line: after its last clause
    return raw[:raw_at(last)] + "; " + new + raw[raw_at(last):]


def write_block(path: os.PathLike, task: str, settings: Mapping[str, Any]) -> str:
    """Replace (or add) ``task``'s train block in the spec file at ``path`` with ``settings``,
    atomically, after the language has checked the new text; the new text is returned.
    :class:`BlockError` (one sentence) when it cannot be, the file then untouched."""
    from asap_dsl import SpecError, loads
    from asap_dsl.runs import RunError, atomic_path

    target = Path(path).resolve()
    try:
        data = target.read_bytes()
        mode = target.stat().st_mode & 0o7777
    except OSError as err:
        raise BlockError(f"cannot read {path}: {err.strerror or err}") from None
    bom = b"\xef\xbb\xbf" if data.startswith(b"\xef\xbb\xbf") else b""
    try:
        raw = data[len(bom):].decode("utf-8")
    except UnicodeDecodeError:
        raise BlockError(f"{path} is not UTF-8 text") from None
    new = replaced_source(raw, task, settings)
    try:
        loads(new, str(path))
    except SpecError as err:
        first = err.errors[0] if getattr(err, "errors", None) else None
        raise BlockError(f"the new train block does not check ({first.message if first else err}); "
                         f"{path} is left as it was") from None
    try:
        with atomic_path(target) as tmp:
            tmp.write_bytes(bom + new.encode("utf-8"))
            os.chmod(tmp, mode)
    except (RunError, OSError) as err:
        raise BlockError(f"cannot write {path}: {getattr(err, 'strerror', None) or err}") from None
    return new
