"""Progress on one line of a terminal, for the commands that work through many states (``oracle``,
``eval``'s ceiling and look-ahead); nothing on a pipe or a log."""

from __future__ import annotations

import time
from typing import TextIO

__all__ = ["LiveLine", "StatesProgress"]


class LiveLine:
    """One line rewritten in place on a terminal, cleared by :meth:`close`; nothing on any other
    stream (a pipe, a log), where a carriage return would only leave debris."""

    def __init__(self, stream: TextIO):
        self.stream, self.shown = stream, False
        self.live = hasattr(stream, "isatty") and stream.isatty()

    def show(self, text: str) -> None:
        if self.live:
            self.stream.write(f"\r  {text}   ")
            self.stream.flush()
            self.shown = True

    def close(self) -> None:
        if self.shown:
            self.stream.write("\r" + " " * 79 + "\r")
            self.stream.flush()
            self.shown = False


class StatesProgress(LiveLine):
    """States done, rate and time left, on one line of a terminal (nothing elsewhere)."""

    def __init__(self, stream: TextIO, task: str, total: int, what: str = "oracle"):
        super().__init__(stream)
        self.task, self.total, self.done, self.what = task, total, 0, what
        self.start = time.perf_counter()

    def __call__(self, k: int) -> None:
        self.done += k
        if not self.live:
            return
        spent = time.perf_counter() - self.start
        rate = self.done / spent if spent > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else float("inf")
        eta = "--" if left == float("inf") else f"{int(left // 60)}m{int(left % 60):02d}s"
        self.show(f"{self.what} {self.task}: {self.done}/{self.total} states, {rate:.2f} states/s, {eta} left")
