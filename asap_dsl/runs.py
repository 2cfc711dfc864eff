"""The run directory: its layout, its manifest, atomic writes and hashes.

A training run lives in one directory (default ``runs/<spec>-<task>-<algo>-<reward>-s<seed>/``)::

    run.json          the manifest: spec path and hash, task, resolved configuration, package
                      versions, status (running | interrupted | finished), steps and wall time
    spec.asap         the spec's source as trained (its sha256 is the manifest's spec_hash)
    model.zip         the policy that scored best on the validation states (stable-baselines3)
    checkpoint/       model.zip, replay.pkl (off-policy), state.json: what --resume needs
    curves.csv        one row per validation: steps, wall time, success rate per tolerance
    tb/               TensorBoard logs
    eval.json         the final evaluation on the seeded evaluation states

Every file is written to a temporary file in the same directory and renamed into place, so an
interruption leaves either the old or the new version, never half of one. Models are pickles:
they are loaded only from a run directory the user names, after its manifest and spec hash check.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Union

__all__ = ["RunError", "RunDir", "atomic_write", "atomic_write_json", "atomic_path", "default_run_name",
           "json_safe", "package_versions", "read_json", "spec_hash"]

MANIFEST = "run.json"
SPEC_COPY = "spec.asap"
MODEL = "model.zip"
CHECKPOINT = "checkpoint"
CURVES = "curves.csv"
EVAL = "eval.json"
TENSORBOARD = "tb"
FORMAT_VERSION = 1

PathLike = Union[str, os.PathLike]
_UMASK = os.umask(0)
os.umask(_UMASK)


class RunError(Exception):
    """A run directory that cannot be used as asked (missing, half-written, from another spec).
    Its message is one plain sentence for the user."""


# ---------------------------------------------------------------------------------------- files
@contextmanager
def atomic_path(path: PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path`` atomically.

    For writers that want a file name (``model.save``); on an exception the temporary is removed
    and ``path`` is left as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + "".join(path.suffixes[-1:]), dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    os.chmod(tmp_path, 0o666 & ~_UMASK)  # mkstemp makes 0600; a run's files are as readable as any other
    try:
        yield tmp_path
        with open(tmp_path, "rb") as f:  # the data is on disk before the name points at it
            os.fsync(f.fileno())
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def atomic_write(path: PathLike, data: Union[str, bytes]) -> None:
    """Write ``data`` to ``path`` atomically (text as UTF-8)."""
    raw = data.encode("utf-8") if isinstance(data, str) else data
    with atomic_path(path) as tmp:
        tmp.write_bytes(raw)


def json_safe(x: Any) -> Any:
    """Strict JSON: non-finite floats become the strings "inf", "-inf", "nan"; numpy scalars and
    arrays become Python numbers and lists."""
    if hasattr(x, "tolist") and not isinstance(x, (str, bytes)):
        x = x.tolist()
    if isinstance(x, float) and not math.isfinite(x):
        return "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf")
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    return x


def atomic_write_json(path: PathLike, obj: Any) -> None:
    atomic_write(path, json.dumps(json_safe(obj), indent=2, allow_nan=False) + "\n")


def spec_hash(source: str) -> str:
    """The sha256 of a spec's source text (what a run, an oracle cache and a report key on)."""
    return hashlib.sha256(source.encode("utf-8")).hexdigest()


def package_versions() -> dict[str, str]:
    """Versions of the packages a result depends on (``missing`` for one not installed)."""
    from importlib import metadata
    import platform

    out = {"python": platform.python_version()}
    for name in ("asap-dsl", "numpy", "torch", "stable-baselines3", "gymnasium", "casadi", "mujoco", "lark", "scipy"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "missing"
    return out


def default_run_name(spec_file: PathLike, task: str, algo: str, reward: str, seed: int) -> str:
    """``<spec>-<task>-<algo>-<reward>-s<seed>``; a reward with parameters keeps only its kind
    and a short hash of the parameters, so that the name is a plain directory name."""
    stem = Path(spec_file).stem
    kind = reward.split("(")[0].strip()
    if "(" in reward:
        kind += "-" + hashlib.sha256(reward.replace(" ", "").encode()).hexdigest()[:6]
    return f"{stem}-{task}-{algo}-{kind}-s{seed}"


# ---------------------------------------------------------------------------------------- runs
class RunDir:
    """A run directory and its manifest (``run.json``)."""

    def __init__(self, path: PathLike):
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunDir({str(self.path)!r})"

    # layout
    @property
    def manifest_path(self) -> Path:
        return self.path / MANIFEST

    @property
    def spec_path(self) -> Path:
        return self.path / SPEC_COPY

    @property
    def model_path(self) -> Path:
        return self.path / MODEL

    @property
    def checkpoint_dir(self) -> Path:
        return self.path / CHECKPOINT

    @property
    def curves_path(self) -> Path:
        return self.path / CURVES

    @property
    def eval_path(self) -> Path:
        return self.path / EVAL

    @property
    def tensorboard_dir(self) -> Path:
        return self.path / TENSORBOARD

    def exists(self) -> bool:
        return self.manifest_path.is_file()

    # manifest
    def read_manifest(self) -> dict:
        """The manifest, or :class:`RunError` in one sentence when it is missing or unreadable."""
        if not self.path.exists():
            raise RunError(f"{self.path}: no such run directory")
        if not self.path.is_dir():
            raise RunError(f"{self.path}: not a directory (a run is a directory written by `asapc train`)")
        if not self.manifest_path.is_file():
            raise RunError(f"{self.path}: not a run directory (it has no {MANIFEST}; was it written by `asapc train`?)")
        try:
            data = json.loads(self.manifest_path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
            raise RunError(f"{self.manifest_path}: unreadable manifest ({_short(err)})") from None
        if not isinstance(data, dict) or data.get("format") != FORMAT_VERSION or "config" not in data:
            raise RunError(f"{self.manifest_path}: not a manifest of this version of asap-dsl")
        return data

    def write_manifest(self, data: dict) -> None:
        data = dict(data)
        data["format"] = FORMAT_VERSION
        atomic_write_json(self.manifest_path, data)

    def update_manifest(self, **changes: Any) -> dict:
        data = self.read_manifest()
        data.update(changes)
        self.write_manifest(data)
        return data

    def read_spec(self) -> str:
        """The spec source as trained, checked against the manifest's hash."""
        manifest = self.read_manifest()
        try:
            source = self.spec_path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError):
            raise RunError(f"{self.path}: the run's copy of its spec ({SPEC_COPY}) is missing or unreadable") from None
        if spec_hash(source) != manifest.get("spec_hash"):
            raise RunError(f"{self.spec_path}: the run's copy of its spec was changed after training "
                           "(its hash no longer matches run.json)")
        return source

    def require_model(self) -> Path:
        if not self.model_path.is_file():
            manifest = self.read_manifest()
            status = manifest.get("status", "unknown")
            raise RunError(f"{self.path}: no trained model yet (run status: {status}; "
                           + ("resume it with `asapc train ... --resume`)" if status != "finished" else "the run is damaged)"))
        return self.model_path


def _short(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return text[0] if text else type(err).__name__


def read_json(path: PathLike, what: str) -> Any:
    """A JSON file written by us, or :class:`RunError` naming it."""
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RunError(f"{path}: missing ({what})") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise RunError(f"{path}: unreadable {what} ({_short(err)})") from None

