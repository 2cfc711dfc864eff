"""Generated step modules on disk, keyed by the hash of their source, compiled once per machine.

numba's ``cache=True`` keeps the machine code of a function beside the file that defines it, so
each generated module is written (atomically, once) to ``<cache dir>/native/<hash>.py``: the
second start of the same spec loads the machine code instead of compiling it. The key is the
sha256 of the source and of the numba, numpy and Python versions, so a changed spec, generator or
toolchain never reads a stale entry. The cache directory is the oracle's: ``$ASAP_CACHE_DIR``, else
``$XDG_CACHE_HOME/asap-dsl`` or ``~/.cache/asap-dsl``.
"""

from __future__ import annotations

import importlib.util
import os
import platform
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

from ..runs import atomic_write, spec_hash

_LOCK = threading.Lock()
_LOADED: dict[str, "Loaded"] = {}


@dataclass(frozen=True)
class Loaded:
    """A compiled module: its functions, where its source is, and what loading it cost."""

    module: ModuleType
    key: str
    path: Path
    seconds: float      # compiling (or loading the machine code) in this process
    from_cache: bool    # machine code found on disk: nothing was compiled


def cache_dir() -> Path:
    """The directory of the project's caches (the same as the oracle's)."""
    if os.environ.get("ASAP_CACHE_DIR"):
        return Path(os.environ["ASAP_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "asap-dsl"


def source_key(source: str) -> str:
    """The cache key of a generated module: its source and the toolchain that compiles it."""
    import numba
    import numpy

    tag = f"\n# numba {numba.__version__} numpy {numpy.__version__} python {platform.python_version()}\n"
    return spec_hash(source + tag)[:24]


def _write(source: str, key: str) -> Path:
    """The module's file, written once; a directory we cannot write is replaced by a temporary one
    (then nothing is kept for the next start)."""
    for base in (cache_dir() / "native", None):
        try:
            d = Path(tempfile.mkdtemp(prefix="asap-native-")) if base is None else base
            d.mkdir(parents=True, exist_ok=True)
            path = d / f"step_{key}.py"
            if not path.is_file() or path.read_text(encoding="utf-8") != source:
                atomic_write(path, source)
            return path
        except OSError:
            continue
    raise OSError("no directory to write the compiled step into")


def _has_machine_code(path: Path) -> bool:
    cache = path.parent / "__pycache__"
    return cache.is_dir() and any(cache.glob(f"{path.stem}.*.nbi"))


def load(source: str, compile_fn) -> Loaded:
    """Import the module of ``source`` and run ``compile_fn(module)`` (numba compiles or loads each
    signature there); once per process and key."""
    key = source_key(source)
    with _LOCK:
        hit = _LOADED.get(key)
        if hit is not None:
            return hit
        path = _write(source, key)
        cached = _has_machine_code(path)
        t0 = time.perf_counter()
        name = f"asap_dsl_native_{key}"
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        try:
            spec.loader.exec_module(module)
            compile_fn(module)
        except BaseException:
            sys.modules.pop(name, None)
            raise
        loaded = _LOADED[key] = Loaded(module, key, path, time.perf_counter() - t0, cached)
        return loaded
