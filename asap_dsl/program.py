"""The public Python API: ``load``/``loads`` a spec into a :class:`Program`.

A program is the checked model plus the objects users evaluate: :class:`Formula` (offline
robustness, satisfaction, first-satisfaction step, online monitors) and :class:`Task`.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

from . import checker, lint, parser
from .diagnostics import Collector, Diagnostic, Span, SpecError, make
from .limits import LIMITS
from .model import ProgramModel, RegionModel, SystemModel, TaskModel, formula_bounds
from .stl import ir


class Formula:
    """A compiled formula over the states of a system."""

    def __init__(self, node: ir.Formula, n_state: int, name: str = "<formula>"):
        self.ir = node
        self.n_state = n_state
        self.name = name

    def __repr__(self) -> str:
        return f"Formula({self.name}: {self.text})"

    @property
    def text(self) -> str:
        return ir.to_text(self.ir)

    @property
    def causal(self) -> bool:
        return ir.is_causal(self.ir)

    @property
    def horizon(self) -> float:
        """Steps into the future the value at t depends on (inf if unbounded)."""
        return ir.horizon(self.ir)

    @property
    def history(self) -> float:
        """Steps into the past the value at t depends on (inf if unbounded)."""
        return ir.history(self.ir)

    @property
    def bounds(self) -> tuple[float, float]:
        """Robustness bounds over the state space, by interval analysis."""
        return formula_bounds(self.ir)

    def robustness(self, traces: Any) -> np.ndarray:
        """Robustness at every step: ``[B, T, n]`` -> ``[B, T]`` (or ``[T, n]`` -> ``[T]``)."""
        from .stl import offline

        return offline.robustness(self.ir, traces, n_state=self.n_state)

    def satisfied(self, traces: Any) -> np.ndarray:
        """Boolean satisfaction at every step (exact comparisons), same shapes as robustness."""
        from .stl import offline

        return offline.satisfied(self.ir, traces, n_state=self.n_state)

    def first_time(self, traces: Any) -> Union[np.ndarray, float]:
        """``t_phi``: the first step at which the formula holds, ``inf`` if never."""
        from .stl import offline

        return offline.first_time(self.ir, traces, n_state=self.n_state)

    def monitor(self, batch: int = 1):
        """An online monitor: ``update(states [B, n]) -> robustness at the newest step``."""
        from .stl import online

        return online.monitor_for(self.ir, batch, n_state=self.n_state)


class Task:
    """A task of the spec: its formulas and settings (see :class:`asap_dsl.model.TaskModel`)."""

    def __init__(self, model: TaskModel, n_state: int):
        self.model = model
        self._n = n_state

    def __repr__(self) -> str:
        return f"Task({self.model.name})"

    def __getattr__(self, item: str):
        return getattr(self.model, item)

    @property
    def asap(self) -> Formula:
        return Formula(self.model.asap, self._n, f"{self.model.name}.asap")

    @property
    def avoid(self) -> Optional[Formula]:
        return None if self.model.avoid is None else Formula(self.model.avoid, self._n, f"{self.model.name}.avoid")

    @property
    def spec(self) -> Formula:
        """``eventually[0, D] asap and always[0, D] not avoid``."""
        return Formula(self.model.spec, self._n, f"{self.model.name}.spec")


class Program:
    """A checked spec. Build one with :func:`load` or :func:`loads`."""

    def __init__(self, model: ProgramModel, warnings: list[Diagnostic]):
        self.model = model
        self.warnings = warnings

    def __repr__(self) -> str:
        return f"Program({self.model.file}: system {self.system.name}, tasks {', '.join(self.tasks)})"

    @property
    def file(self) -> str:
        return self.model.file

    @property
    def source(self) -> str:
        return self.model.source

    @property
    def system(self) -> SystemModel:
        return self.model.system

    @property
    def tasks(self) -> tuple[str, ...]:
        return tuple(self.model.tasks)

    @property
    def formulas(self) -> tuple[str, ...]:
        return tuple(self.model.formulas)

    @property
    def regions(self) -> dict[str, RegionModel]:
        return dict(self.model.regions)

    def formula(self, name: str) -> Formula:
        if name not in self.model.formulas:
            raise KeyError(_missing("formula", name, self.formulas))
        return Formula(self.model.formulas[name].ir, self.system.n_state, name)

    def task(self, name: Optional[str] = None) -> Task:
        """The named task; without a name, the only task (an error if there are several)."""
        if name is None:
            if len(self.tasks) != 1:
                raise KeyError(f"{self.file} has tasks {', '.join(self.tasks) or '(none)'}: name one")
            name = self.tasks[0]
        if name not in self.model.tasks:
            raise KeyError(_missing("task", name, self.tasks, self.file))
        return Task(self.model.tasks[name], self.system.n_state)


def _missing(kind: str, name: str, known: tuple[str, ...], file: Optional[str] = None) -> str:
    """The one wording of an unknown task (or formula) name, everywhere it can be given."""
    from .diagnostics import closest

    sug = closest(name, known)
    tail = f"; did you mean '{sug}'?" if sug else f"; the file has: {', '.join(known) or 'none'}"
    return f"no {kind} named '{name}'" + (f" in {file}" if file else "") + tail


def normalise_newlines(text: str) -> str:
    """``\\r\\n`` and a lone ``\\r`` become ``\\n``, so that line numbers are the ones an editor shows."""
    return text.replace("\r\n", "\n").replace("\r", "\n") if "\r" in text else text


def analyse(text: str, name: str = "<string>") -> tuple[Optional[ProgramModel], list[Diagnostic]]:
    """Parse, check and lint; return the model (None on errors) and every diagnostic, sorted."""
    text = normalise_newlines(text)
    module, structural = parser.parse(text, name)
    diag = Collector(name, list(structural))
    try:
        model = checker.check(module, text, diag)
        if model is not None:
            lint.lint(model, diag)
    except RecursionError:  # formulas defined through ~1,000 others: a real limit, said in words
        raise SpecError([make("E001", "the spec nests too deeply to check: formulas or expressions are defined "
                              "through more than about 900 levels of others", Span(0, 0, 0, 0), name,
                              hint="split the chain: define intermediate formulas with fewer levels each")],
                        text) from None
    if diag.has_errors:
        model = None
    return model, diag.sorted()


def loads(text: str, name: str = "<string>") -> Program:
    """Parse, check and lint a spec given as text.

    :param text: the spec's source (``\r\n`` and ``\r`` line ends are read as ``\n``)
    :param name: the file name that diagnostics give (it is not read)
    :return: the checked program; its ``warnings`` hold the lint warnings
    :raises SpecError: with every error of the spec at once (positioned, each in one sentence)
    """
    text = normalise_newlines(text)
    model, diagnostics = analyse(text, name)
    if model is None:
        raise SpecError(diagnostics, text)
    return Program(model, [d for d in diagnostics if not d.is_error])


def _read_regular_file(p: Path, name: str, limit: int) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes. Devices, pipes and sockets are
    refused before anything is read (``/dev/zero`` never ends, a FIFO blocks)."""
    def fail(message: str, hint: Optional[str] = None) -> SpecError:
        return SpecError([make("E002", message, Span(0, 0, 0, 0), name, hint=hint)])

    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise fail("no such file") from None
    except IsADirectoryError:
        raise fail("this is a directory, not a spec file") from None
    except PermissionError:
        raise fail("permission denied") from None
    except OSError as err:
        raise fail(f"cannot read the file: {err.strerror or err}") from None
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode):
        os.close(fd)
        if stat.S_ISDIR(info.st_mode):
            raise fail("this is a directory, not a spec file")
        raise fail("not a regular file (a device, pipe or socket): a spec is a text file on disk")
    with os.fdopen(fd, "rb") as f:
        too_big = fail(f"the file is larger than the limit of {limit / 2**20:g} MB",
                       hint="a spec is a few kilobytes; raise the limit with `asapc --max-spec-size MB`")
        if info.st_size > limit:
            raise too_big
        try:
            data = f.read(limit + 1)
        except OSError as err:
            raise fail(f"cannot read the file: {err.strerror or err}") from None
        if len(data) > limit:  # it grew while being read
            raise too_big
    return data


def read_source(path: Union[str, os.PathLike], max_bytes: Optional[int] = None) -> str:
    """Read a spec file as UTF-8 text, turning every way of failing into a positioned SpecError.

    Only regular files of at most ``max_bytes`` (default ``LIMITS.spec_bytes``) are read; a
    UTF-8 byte-order mark is skipped.
    """
    p = Path(path)
    name = str(path)
    whole = Span(1, 1, 1, 2)
    data = _read_regular_file(p, name, LIMITS.spec_bytes if max_bytes is None else int(max_bytes))
    if data.startswith(b"\xef\xbb\xbf"):  # a BOM that some editors write: not part of the text
        data = data[3:]
    try:
        text = normalise_newlines(data.decode("utf-8"))
    except UnicodeDecodeError as err:
        line = data[: err.start].count(b"\n") + 1
        col = err.start - (data.rfind(b"\n", 0, err.start) + 1) + 1
        raise SpecError([make("E002", f"the file is not UTF-8 text (byte 0x{data[err.start]:02x} at offset {err.start})",
                              Span(line, col, line, col + 1), name)]) from None
    if "\x00" in text:
        at = text.index("\x00")
        line = text.count("\n", 0, at) + 1
        col = at - (text.rfind("\n", 0, at) + 1) + 1
        raise SpecError([make("E002", "the file contains a NUL byte: it is binary, not a spec", Span(line, col, line, col + 1), name)],
                        text) from None
    if not text.strip():
        raise SpecError([make("E002", "the file is empty", whole, name,
                              hint="a spec declares a system, its regions, formulas and tasks")], text)
    return text


def load(path: Union[str, os.PathLike]) -> Program:
    """Read, parse, check and lint a ``.asap`` file.

    :param path: the file: a regular file of UTF-8 text, at most ``LIMITS.spec_bytes``
        (``asapc --max-spec-size``); a byte-order mark is skipped
    :return: the checked program; its ``warnings`` hold the lint warnings
    :raises SpecError: E002 if the file cannot be read as a spec (missing, a directory or device,
        too large, not UTF-8, binary, empty), else every error of the spec at once
    """
    return loads(read_source(path), str(path))


__all__ = ["Formula", "Task", "Program", "load", "loads", "analyse", "read_source"]
