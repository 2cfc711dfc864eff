"""The limits that keep every input within bounded time and memory, in one place.

Each is far beyond any real spec and stops input that would otherwise hang or exhaust the
machine. ``asapc``'s global flags raise the ones that are a matter of resources
(``--max-spec-size MB``, ``--max-deadline STEPS``, ``--max-substeps N``); from Python, set the
fields of :data:`LIMITS` (or use :func:`raised`). The nesting limits are not flags: they keep
the tree walks within Python's stack, and a chain (a + b + ..., a and b and ...) never counts.
The processes a run may start are bounded by the cores (:func:`available_cores`), the batches it
steps (``--envs``, evaluation states) by the memory (:func:`check_memory`).
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass, fields, replace
from typing import Iterator


@dataclass
class Limits:
    #: bytes of a spec file read (``asapc --max-spec-size MB``)
    spec_bytes: int = 10 * 1024 * 1024
    #: steps of the longest deadline, hence of every episode, window and oracle horizon
    #: (``asapc --max-deadline STEPS``); windows longer than the deadline are cut to it
    deadline_steps: int = 1_000_000
    #: integrator substeps per step (``asapc --max-substeps N``)
    substeps: int = 1000
    #: initial states of one evaluation or oracle run
    episodes: int = 1_000_000
    #: nested operators in one expression as written (parentheses, calls, not, -, temporal)
    nesting: int = 100
    #: nested operators of a formula with the formulas it uses written out
    formula_depth: int = 200
    #: nodes of a formula with the formulas it uses written out (one used twice counts twice)
    formula_size: int = 100_000


#: The limits in force in this process.
LIMITS = Limits()


@contextlib.contextmanager
def raised(**changes: int) -> Iterator[Limits]:
    """``with raised(deadline_steps=10**7): ...``: other limits for the block, then the old ones."""
    names = {f.name for f in fields(Limits)}
    unknown = set(changes) - names
    if unknown:
        raise TypeError(f"unknown limit(s) {', '.join(sorted(unknown))}; the limits are {', '.join(sorted(names))}")
    old = replace(LIMITS)
    for k, v in changes.items():
        setattr(LIMITS, k, int(v))
    try:
        yield LIMITS
    finally:
        for f in fields(Limits):
            setattr(LIMITS, f.name, getattr(old, f.name))


def available_cores() -> int:
    """The cores this process may run on: the default number of worker processes everywhere, and
    their cap unless forced (more processes than cores only slow every one of them down)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def available_memory() -> int:
    """Bytes this process can still allocate: the system's available memory, within the cgroup's
    limit (a container) and the address-space limit (``ulimit -v``) when they are lower."""
    free = []
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    free.append(int(line.split()[1]) * 1024)
    except (OSError, ValueError, IndexError):
        pass
    try:
        limit = open("/sys/fs/cgroup/memory.max", encoding="ascii").read().strip()
        used = int(open("/sys/fs/cgroup/memory.current", encoding="ascii").read().strip())
        if limit.isdigit():
            free.append(max(0, int(limit) - used))
    except (OSError, ValueError):
        pass
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft != resource.RLIM_INFINITY:
            free.append(soft)
    except (ImportError, OSError, ValueError):
        pass
    if not free:
        try:
            free.append(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (OSError, ValueError):
            return 1 << 62
    return min(free)


class ResourceLimit(ValueError):
    """A setting that needs more memory than the machine has: one sentence (exit 2)."""


def batch_bytes(prog, task: str, reward=None) -> int:
    """Bytes of memory one entry of a batched environment of ``task`` takes (states, monitors and
    their windows, the reward's state), measured: the environment is built and stepped for 1 and
    for 65 entries and the difference divided (the allocations numpy reports to tracemalloc)."""
    import tracemalloc

    import numpy as np

    from .env import make_vec_env

    def build(batch: int) -> None:
        env = make_vec_env(prog, task, num_envs=batch, seed=0, reward=reward)
        env.reset()
        env.step(np.zeros((batch,) + env.action_space.shape, dtype=np.float32))

    build(1)  # what is allocated once (compiled code, caches) is not counted per entry
    peaks = []
    for batch in (1, 65):
        tracemalloc.start()
        try:
            build(batch)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
    return max(64, (peaks[1] - peaks[0]) // 64)


def check_memory(count: int, per_entry: int, what: str, fixed: int = 0) -> None:
    """Refuse ``count`` entries of ``per_entry`` bytes (plus ``fixed``) beyond three quarters of
    :func:`available_memory`, naming ``what`` (the flag) in one sentence."""
    need = int(count) * int(per_entry) + int(fixed)
    have = available_memory()
    if need > 0.75 * have:
        raise ResourceLimit(f"{what} needs about {_size(need)} of memory, more than the {_size(have)} this machine "
                            "has available; use fewer")


def check_batch(prog, task: str, count: int, what: str, reward=None, extra: int = 0) -> None:
    """:func:`check_memory` for ``count`` entries of a batched environment of ``task`` and ``extra``
    bytes each beside it (a policy's activations); measured (:func:`batch_bytes`) only when the
    batch could matter at all."""
    if int(count) * (int(extra) + 65536) < available_memory() / 20:
        return
    check_memory(count, batch_bytes(prog, task, reward) + int(extra), what)


def _size(n: float) -> str:
    for unit in ("bytes", "KB", "MB", "GB", "TB"):
        if n < 1024 or unit == "TB":
            return f"{n:,.0f} {unit}" if unit == "bytes" else f"{n:,.1f} {unit}"
        n /= 1024
    return f"{n:,.1f} TB"  # pragma: no cover


__all__ = ["LIMITS", "Limits", "ResourceLimit", "available_cores", "available_memory", "batch_bytes", "check_batch",
           "check_memory", "raised"]
