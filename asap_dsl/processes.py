"""Signals and child processes: how a run stops on request without losing its files, and how a
worker process never outlives the process that started it.

:class:`Interrupts` turns Ctrl-C and SIGTERM into a request to stop at the next safe point. Writes
that must not be cut (a checkpoint) run inside :meth:`Interrupts.critical`: a second signal then
waits for them, saying so; a third aborts (:class:`Aborted`), saying what is lost. A signal that
was ignored when the handler was installed (a background job's SIGINT, a sweep worker's) stays
ignored.

:func:`die_with_parent` makes a worker die with its parent: ``prctl(PR_SET_PDEATHSIG)`` on Linux,
and a thread that watches the parent's PID on every system (and covers a parent that died before
the ``prctl``).
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time
from contextlib import contextmanager
from typing import Callable, Iterator, Optional

__all__ = ["Aborted", "Interrupts", "die_with_parent", "pool_size", "pool_worker"]

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Aborted(KeyboardInterrupt):
    """A third Ctrl-C (or SIGTERM) ended a write that the first two waited for."""


def _say(text: str) -> None:
    try:
        os.write(2, (text + "\n").encode("utf-8", "replace"))
    except OSError:
        pass


class Interrupts:
    """Ctrl-C and SIGTERM as a request to stop (:attr:`signal`, the first received).

    ``with Interrupts() as stop:`` installs the handlers (main thread only; elsewhere it only
    counts nothing) and restores the previous ones on exit. ``raise_outside``: a signal that
    arrives outside a critical section raises ``KeyboardInterrupt`` at once instead of asking
    (for phases that have nothing to save). ``on_signal(signum)`` is called on every signal first
    (a sweep forwards it to its workers).
    """

    def __init__(self, signals=STOP_SIGNALS, raise_outside: bool = False,
                 on_signal: Optional[Callable[[int], None]] = None):
        self.signals = tuple(signals)
        self.raise_outside = raise_outside
        self.on_signal = on_signal
        self.signal: Optional[int] = None
        self.count = 0
        self._old: dict = {}
        self._critical: list[str] = []
        self._pid = os.getpid()

    # -- installing
    def __enter__(self) -> "Interrupts":
        self._pid = os.getpid()
        if threading.current_thread() is threading.main_thread():
            for sig in self.signals:
                if signal.getsignal(sig) is signal.SIG_IGN:
                    continue  # ignored by whoever started us (nohup, a sweep's worker): keep it so
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> bool:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()
        return False

    @property
    def requested(self) -> bool:
        return self.signal is not None

    # -- the handler
    def _handle(self, signum, frame) -> None:
        if os.getpid() != self._pid:  # a forked child (a pool's worker) inherited us: die as by default
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        self.count += 1
        if self.signal is None:
            self.signal = signum
        if self.on_signal is not None:
            self.on_signal(signum)
        what = self._critical[-1] if self._critical else None
        if what is None and self.raise_outside:
            raise KeyboardInterrupt
        if self.count == 1:
            return
        if self.count == 2:
            _say(f"asapc: still saving {what}; press Ctrl-C once more to abort without it" if what else
                 "asapc: stopping at the next step to save a checkpoint; press Ctrl-C once more to abort without it")
            return
        _say(f"asapc: aborted: {what} was not saved (the previous one is kept)" if what else
             "asapc: aborted before the checkpoint (the previous one is kept)")
        raise Aborted("aborted")

    @contextmanager
    def critical(self, what: str) -> Iterator[None]:
        """A write that a signal must not cut: the first two signals wait for it."""
        self._critical.append(what)
        try:
            yield
        finally:
            self._critical.pop()
            if self.raise_outside and self.signal is not None and not self._critical:
                raise KeyboardInterrupt


# ------------------------------------------------------------------------------------ workers
_PR_SET_PDEATHSIG = 1


def _set_parent_death_signal(sig: int) -> bool:
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def die_with_parent(parent: int, sig: int = signal.SIGKILL, every: float = 1.0) -> None:
    """Make this process die (``sig``) when process ``parent`` (its parent) ends.

    Call it first thing in a worker. ``PR_SET_PDEATHSIG`` makes the kernel send ``sig`` when the
    parent exits; a daemon thread checks the parent's PID every ``every`` seconds as well (other
    systems, and a parent that died before the call: the worker then belongs to init).
    """
    _set_parent_death_signal(sig)
    if os.getppid() != parent:
        os.kill(os.getpid(), sig)

    def watch() -> None:
        while True:
            time.sleep(every)
            if os.getppid() != parent:
                os.kill(os.getpid(), sig)
                return

    threading.Thread(target=watch, name="die-with-parent", daemon=True).start()


def pool_worker(parent: int) -> None:
    """A ``multiprocessing.Pool`` worker's start (its ``initializer``, with the pool's owner's PID):
    the pool's terminate (SIGTERM) ends it quietly, whatever handler it inherited; Ctrl-C is the
    owner's to handle (it terminates the pool); and it dies with the owner, whose ``kill -9``
    would otherwise leave it waiting on the pool's queue for ever."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(parent)


def pool_size(workers: int) -> int:
    """How many processes a pool of ``workers`` may have here: one (no pool) inside a daemonic
    process — a sweep's worker training with demonstrations, say — which may not have children."""
    import multiprocessing as mp

    return 1 if mp.current_process().daemon else workers


def wall_timeout(until: Optional[float], cap_seconds: float, state_seconds: float) -> Optional[float]:
    """How long a pool's owner may still wait for a worker's result under a wall-clock cap that
    ends at ``until`` (``time.time()``; None: no cap, wait for ever): a state begun before the cap
    may finish after it, for at most one state's ``state_seconds`` and a tenth of the cap's
    ``cap_seconds`` (at least a second). Past that the owner gives up what is still running
    (leaving the pool terminates it): workers spawned on a loaded machine take tens of seconds to
    start, and a run's time limit must hold all the same."""
    if until is None:
        return None
    grace = min(float(state_seconds), max(1.0, 0.1 * float(cap_seconds)))
    return max(0.0, until + grace - time.time())
