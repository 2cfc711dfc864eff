"""The run directory: its layout, its manifest, its lock, and how its files are written and read.

A training run lives in one directory (default ``runs/<spec>-<task>-<algo>-<reward>-s<seed>/``)::

    run.json          the manifest: spec path (absolute) and hash, task, resolved configuration,
                      package versions, status (running | interrupted | finished | failed), steps,
                      wall time, and the size and sha256 of the model and of every checkpoint file
    spec.asap         the spec's source as trained (its sha256 is the manifest's spec_hash)
    model.zip         the policy that scored best on the validation states
    checkpoint/       model.zip, replay.pkl (off-policy), state.pkl, state.json: what --resume needs
    curves.csv        one row per validation: steps, wall time, success rate per tolerance
    tb/               TensorBoard logs
    eval.json         the final evaluation on the seeded evaluation states (with the model's hash)
    .lock             the lock (``flock``): exclusive while a process trains, shared while one reads

What holds, whatever happens to the process (docs/training.md, "What a run survives"):

- **One owner.** Training, resuming and replacing take the exclusive lock, evaluating and reports
  a shared one; a refusal names the process that holds it.
- **Created whole.** A new run is built in a hidden directory beside its name (manifest, spec, a
  checkpoint at step 0) and renamed into place: a run directory that exists can be resumed.
  ``--force`` replaces only a directory that is a run, by exchanging it with the new one.
- **The manifest is the commit point.** A checkpoint or a model is written in full beside its
  name, then the manifest records its size and sha256, then it is renamed in. A kill at any
  moment leaves the previous checkpoint valid; a file that does not match its record (damaged,
  deleted, swapped in from another run) is refused in one sentence.
- **Write failures are sentences.** A full disk or a read-only directory stops the run with the
  path and the reason; the partial files are removed, the status says ``failed`` and why, and the
  last checkpoint stays valid for ``--resume``.
"""

from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import re
import tempfile
import time
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Optional, Union

from .runschema import FORMAT_VERSION, STATUSES, check_manifest, evaluation_problem, read_curves
from .runfiles import (_UMASK, LOCK_FILE, DirLock, RunBusy, RunError, RunWriteError, _reason, atomic_path,
                       atomic_write, command_line, exchange, file_record, fsync_dir, is_write_error, lock_dir,
                       record_mismatch, remove_tree, shell_quote, shown, writing)

__all__ = ["FORMAT_VERSION", "STATUSES", "Checkpoint", "RunBusy", "RunDir", "RunError", "RunWriteError", "atomic_path", "atomic_write",
           "atomic_write_json", "check_target", "checkpoint_seconds", "command_line", "create_run", "default_run_name", "json_safe",
           "package_versions", "read_json", "shell_quote", "spec_hash"]

MANIFEST = "run.json"
SPEC_COPY = "spec.asap"
MODEL = "model.zip"
CHECKPOINT = "checkpoint"
CURVES = "curves.csv"
EVAL = "eval.json"
TENSORBOARD = "tb"
EXAMPLES = "examples.json"  # a run summary's recorded example actions (asap_dsl.runsummary)
# The policy refined by the look-ahead (asapc compare --lookahead) on the first N evaluation states:
# derived from the model like eval.json, kept beside it so that a summary carries it too.
LOOKAHEAD = "lookahead{hold}-n{states}.json"
_LOOKAHEAD = r"lookahead\d+-n\d+\.json"

PathLike = Union[str, os.PathLike]
Writer = Callable[[Path], None]

_FILES = (MANIFEST, SPEC_COPY, MODEL, CURVES, EVAL, EXAMPLES)
# The names a run directory may hold: its files, their temporaries, checkpoint stages, the lock.
_NAMES = "|".join([*map(re.escape, _FILES), _LOOKAHEAD])
_RUN_ENTRY = re.compile(r"^(?:%s|%s|%s|\.lock|checkpoint\.(?:new|old)|\.(?:%s)\..+\.tmp(?:\.\w+)?)$" % (
    _NAMES, CHECKPOINT, TENSORBOARD, _NAMES))
LOOKAHEAD_FILE = re.compile(f"^{_LOOKAHEAD}$")


def checkpoint_seconds() -> float:
    """Wall time between periodic checkpoints: 120 s, or ``ASAP_CHECKPOINT_SECONDS``."""
    try:
        value = float(os.environ.get("ASAP_CHECKPOINT_SECONDS", "120"))
    except ValueError:
        return 120.0
    return value if value > 0 and math.isfinite(value) else 120.0


# ---------------------------------------------------------------------------------------- files
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
    """``obj`` as strict, indented JSON, written atomically."""
    atomic_write(path, json.dumps(json_safe(obj), indent=2, allow_nan=False) + "\n")


def spec_hash(source: str) -> str:
    """The sha256 of a spec's source text (what a run, an oracle cache and a report key on)."""
    return hashlib.sha256(source.encode("utf-8")).hexdigest()


def package_versions() -> dict[str, str]:
    """Versions of the packages a result depends on (``missing`` for one not installed)."""
    from importlib import metadata
    import platform

    out = {"python": platform.python_version()}
    for name in ("asap-dsl", "numpy", "torch", "stable-baselines3", "sbx-rl", "jax", "gymnasium", "casadi", "mujoco",
                 "lark", "scipy"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "missing"
    return out


def default_run_name(spec_file: PathLike, task: str, algo: str, reward: str, seed: int) -> str:
    """``<spec>-<task>-<algo>-<reward>-s<seed>``; a reward with parameters keeps only its kind
    and a short hash of the parameters, so that the name is a plain directory name."""
    # A file name may hold anything but "/" and NUL: control characters and spaces become "_"
    # (a newline or an escape in a directory name breaks every listing and shell that shows it).
    stem = re.sub(r"[\x00-\x20\x7f]", "_", Path(spec_file).stem) or "spec"
    kind = reward.split("(")[0].strip()
    if "(" in reward:
        kind += "-" + hashlib.sha256(reward.replace(" ", "").encode()).hexdigest()[:6]
    return f"{stem}-{task}-{algo}-{kind}-s{seed}"


def read_json(path: PathLike, what: str) -> Any:
    """A JSON file written by us, or :class:`RunError` naming it."""
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RunError(f"{shown(path)}: missing ({what})") from None
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:  # RecursionError: nested too deep
        raise RunError(f"{shown(path)}: unreadable {what} ({_short(err)})") from None


def _short(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return text[0] if text else type(err).__name__


# ---------------------------------------------------------------------------------------- runs
class Checkpoint:
    """A checkpoint whose files match the manifest's record: ``path(name)`` is safe to load."""

    def __init__(self, directory: Path, record: dict):
        self.directory, self.steps, self.files = directory, int(record["steps"]), dict(record["files"])

    def has(self, name: str) -> bool:
        return name in self.files

    def path(self, name: str) -> Path:
        if name not in self.files:
            raise RunError(f"{shown(self.directory)}: the checkpoint has no {name}")
        return self.directory / name


class RunDir:
    """A run directory (its path made absolute and resolved), its manifest and its lock."""

    def __init__(self, path: PathLike):
        self.path = Path(path).expanduser().resolve()
        self.lock: Optional[DirLock] = None
        self.interrupts = None  # an asap_dsl.processes.Interrupts: then every commit is a critical section

    def __repr__(self) -> str:
        return f"RunDir({str(self.path)!r})"

    # -- layout
    manifest_path = property(lambda self: self.path / MANIFEST)
    spec_path = property(lambda self: self.path / SPEC_COPY)
    model_path = property(lambda self: self.path / MODEL)
    checkpoint_dir = property(lambda self: self.path / CHECKPOINT)
    curves_path = property(lambda self: self.path / CURVES)
    eval_path = property(lambda self: self.path / EVAL)
    tensorboard_dir = property(lambda self: self.path / TENSORBOARD)

    def exists(self) -> bool:
        return self.manifest_path.is_file()

    # -- the lock
    def acquire(self, exclusive: bool) -> "RunDir":
        """Take the run's lock (exclusive to write, shared to read); :class:`RunBusy` when another
        process holds it. An exclusive holder first finishes what a killed writer left half done."""
        if self.lock is not None and self.lock.held and (self.lock.exclusive or not exclusive):
            return self
        self._require_dir()
        hint = ("wait for it to finish, or stop it, then run this again" if exclusive else
                "wait for it to finish, then run this again")
        self.lock = lock_dir(self.path, exclusive, wait_hint=hint)
        if exclusive:
            self._recover()
        return self

    def release(self) -> None:
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    def __enter__(self) -> "RunDir":
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def _require_dir(self) -> None:
        if not self.path.exists():
            raise RunError(f"{shown(self.path)}: no such run directory")
        if not self.path.is_dir():
            raise RunError(f"{shown(self.path)}: not a directory (a run is a directory written by `asapc train`)")

    def _critical(self, what: str):
        return self.interrupts.critical(what) if self.interrupts is not None else nullcontext()

    # -- the manifest
    def read_manifest(self) -> dict:
        """The manifest, checked against its schema, or :class:`RunError` in one sentence."""
        self._require_dir()
        if not self.manifest_path.is_file():
            raise RunError(f"{shown(self.path)}: not a run directory (it has no {MANIFEST}; was it written by "
                           "`asapc train`?)")
        try:
            data = json.loads(self.manifest_path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:  # RecursionError: nested too deep
            raise RunError(f"{shown(self.manifest_path)}: unreadable manifest ({_short(err)}); replace the run "
                           "with `asapc train ... --force`") from None
        return check_manifest(data, self.manifest_path)

    def write_manifest(self, data: Mapping[str, Any]) -> None:
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
            raise RunError(f"{shown(self.path)}: the run's copy of its spec ({SPEC_COPY}) is missing or unreadable") from None
        if spec_hash(source) != manifest["spec_hash"]:
            raise RunError(f"{shown(self.spec_path)}: the run's copy of its spec was changed after training "
                           "(its hash no longer matches run.json)")
        return source

    # -- what to type next
    def command(self, manifest: Mapping[str, Any], how: str) -> str:
        """``asapc train SPEC --task T --out RUN --resume`` (or ``--force``), ready to paste."""
        return command_line(["asapc", "train", manifest.get("spec_file", "SPEC"), "--task", manifest.get("task", "T"),
                             "--out", str(self.path), how])

    def status_text(self, manifest: Mapping[str, Any]) -> str:
        status = manifest["status"]
        if status == "running" and self.lock is None:
            from .runfiles import holder

            if holder(self.path) is None:
                return "stopped without saying why (killed?)"
        if status == "failed" and manifest.get("error"):
            return f"failed: {manifest['error']}"
        return status

    # -- the best model
    def save_model(self, write: Writer, **changes: Any) -> dict:
        """Write the best model: in full beside its name, recorded in the manifest (with
        ``changes``), then renamed in. Returns its record."""
        with self._critical("the best model"):
            with atomic_path(self.model_path) as tmp:
                with writing(self.model_path, exact=True):
                    write(tmp)
                record = file_record(tmp)
                self.update_manifest(model=record, **changes)
        return record

    def model_file(self, manifest: Optional[Mapping[str, Any]] = None) -> Path:
        """The best model's path, once it is checked against the manifest's record; a model that
        is missing, damaged or swapped in from another run is refused."""
        manifest = manifest if manifest is not None else self.read_manifest()
        record = manifest.get("model")
        if record is None:
            how = "--resume" if manifest.get("checkpoint") else "--force"
            raise RunError(f"{shown(self.path)}: no trained model yet (the run is {self.status_text(manifest)}); "
                           f"continue it with `{self.command(manifest, how)}`")
        why = record_mismatch(self.model_path, record)
        if why is None:
            return self.model_path
        for staged in self._staged(MODEL):  # renamed in after the manifest named it: a kill came between
            if record_mismatch(staged, record) is None:
                return staged
        raise RunError(f"{shown(self.model_path)}: not the model this run wrote ({why}); it was damaged or "
                       f"replaced, and is refused: train the run again with `{self.command(manifest, '--force')}`")

    # -- checkpoints
    def save_checkpoint(self, files: Mapping[str, Writer], steps: int, **changes: Any) -> Checkpoint:
        """Write a checkpoint: every file into ``checkpoint.new``, their records into the manifest
        (with ``changes``: the commit), then ``checkpoint.new`` exchanged with ``checkpoint``.
        A failure or a kill before the commit leaves the previous checkpoint as the valid one."""
        stage = self.path / f"{CHECKPOINT}.new"
        with self._critical("the checkpoint"):
            remove_tree(stage)
            try:
                with writing(stage):
                    stage.mkdir()
                records = {}
                for name, write in files.items():
                    target = stage / name
                    with writing(target):
                        write(target)
                        with open(target, "rb+") as f:
                            os.fsync(f.fileno())
                    records[name] = file_record(target)
                fsync_dir(stage)
                record = {"steps": int(steps), "files": records}
                self.update_manifest(checkpoint=record, **changes)
            except BaseException:
                remove_tree(stage)
                raise
            self._install(stage, self.checkpoint_dir)
        return Checkpoint(self.checkpoint_dir, record)

    def checkpoint(self, manifest: Optional[Mapping[str, Any]] = None) -> Optional[Checkpoint]:
        """The checkpoint the manifest records, its files checked (None: the run has none)."""
        manifest = manifest if manifest is not None else self.read_manifest()
        record = manifest.get("checkpoint")
        if record is None:
            return None
        first = None
        for d in self._checkpoint_candidates():
            bad = [(name, why) for name, r in record["files"].items() for why in [record_mismatch(d / name, r)] if why]
            if not bad:
                return Checkpoint(d, record)
            first = first or (d / bad[0][0], bad[0][1])
        where, why = first
        raise RunError(f"{shown(where)}: damaged checkpoint ({why}); the run cannot resume from it: train it again "
                       f"with `{self.command(manifest, '--force')}`")

    def _checkpoint_candidates(self) -> list[Path]:
        return [self.checkpoint_dir, self.path / f"{CHECKPOINT}.new", self.path / f"{CHECKPOINT}.old"]

    def _install(self, stage: Path, final: Path) -> None:
        if final.exists():
            exchange(stage, final)
            remove_tree(stage)  # the previous one, now under the stage's name
        else:
            with writing(final):
                os.rename(stage, final)
            fsync_dir(final.parent)

    def _staged(self, name: str) -> list[Path]:
        return sorted(self.path.glob(f".{name}.*.tmp*"))

    def _recover(self) -> None:
        """Under the exclusive lock: finish a commit that a kill cut between the manifest and the
        rename, and remove what a killed writer left half written."""
        try:
            manifest = self.read_manifest()
        except RunError:
            return
        try:
            record = manifest.get("model")
            if record is not None and record_mismatch(self.model_path, record) is not None:
                for staged in self._staged(MODEL):
                    if record_mismatch(staged, record) is None:
                        os.replace(staged, self.model_path)
                        break
            for name in _FILES:
                for staged in self._staged(name):
                    remove_tree(staged)
            try:
                ckpt = self.checkpoint(manifest)
            except RunError:
                ckpt = None  # reported when it is read
            if ckpt is not None and ckpt.directory != self.checkpoint_dir:
                self._install(ckpt.directory, self.checkpoint_dir)
            if ckpt is not None:
                for d in self._checkpoint_candidates()[1:]:
                    remove_tree(d)
        except (OSError, RunWriteError):
            pass  # a read-only run: nothing to finish, and the next write says why

    # -- evaluation and curves
    def write_eval(self, evaluation: Mapping[str, Any], model: Path) -> None:
        """``eval.json``, tied to the model it evaluated by that model's sha256."""
        data = dict(evaluation)
        data["model_sha256"] = file_record(model)["sha256"]
        atomic_write_json(self.eval_path, data)

    def lookahead_path(self, hold: int, states: int) -> Path:
        return self.path / LOOKAHEAD.format(hold=int(hold), states=int(states))

    def write_lookahead(self, evaluation: Mapping[str, Any], hold: int, states: int, model_sha256: str) -> Path:
        """The policy's evaluation refined by a look-ahead holding up to ``hold`` steps on the
        first ``states`` evaluation states, tied to the model it refined by its sha256."""
        path = self.lookahead_path(hold, states)
        atomic_write_json(path, {**evaluation, "model_sha256": model_sha256})
        return path

    def read_lookahead(self, hold: int, states: int, manifest: Mapping[str, Any]) -> Optional[dict]:
        """That evaluation, or None: not made, unreadable, or of another model than the manifest's
        (the next refinement replaces it)."""
        path = self.lookahead_path(hold, states)
        if not path.is_file():
            return None
        try:
            data = read_json(path, "look-ahead evaluation")
        except RunError:
            return None
        sha = (manifest.get("model") or {}).get("sha256")
        ok = isinstance(data, dict) and sha is not None and data.get("model_sha256") == sha and "rows" in data
        return data if ok else None

    def read_eval(self, manifest: Optional[Mapping[str, Any]] = None) -> dict:
        """``eval.json``, checked: its shape, and that it evaluated this run's spec and model."""
        manifest = manifest if manifest is not None else self.read_manifest()
        data = read_json(self.eval_path, "evaluation")
        why = evaluation_problem(data, manifest)
        if why is not None:
            raise RunError(f"{shown(self.eval_path)}: {why}; evaluate the run again with "
                           f"`{command_line(['asapc', 'eval', str(self.path)])}`")
        return data

    def write_curves(self, text: str) -> None:
        atomic_write(self.curves_path, text)

    def read_curves(self) -> list[dict]:
        """``curves.csv`` as rows of numbers by column ([] when the run has none yet)."""
        return read_curves(self.curves_path)

    # -- failures
    @contextmanager
    def guard(self, status: str = "failed") -> Iterator[None]:
        """A failed write inside becomes one :class:`RunError` (:meth:`failed`): the status
        records it, the partial files go, the sentence says what is kept and what to run next."""
        try:
            yield
        except RunWriteError as err:
            raise self.failed(err, status) from None
        except OSError as err:
            if not is_write_error(err):
                raise
            raise self.failed(RunWriteError(err.filename or self.path, _reason(err), code=err.errno), status) from None

    def failed(self, err: RunWriteError, status: str = "failed") -> RunError:
        """Record a write failure in the manifest (best effort: the disk may be full) and return
        the sentence the user reads: the path, the reason, what is kept, and what to run next."""
        self._recover()  # a commit cut short is finished, the partial files removed
        remove_tree(self.path / f"{CHECKPOINT}.new")
        manifest: dict = {}
        try:
            manifest = self.update_manifest(status=status, error=str(err))
        except RunError:
            try:
                manifest = self.read_manifest()
            except RunError:
                pass
        ckpt = manifest.get("checkpoint")
        kept = (f"the checkpoint at step {ckpt['steps']:,} is intact" if ckpt else "nothing was saved")
        fix = err.remedy
        nxt = (f"continue with `{self.command(manifest, '--resume')}`" if ckpt and status != "finished" else
               f"evaluate it with `{command_line(['asapc', 'eval', str(self.path)])}`" if status == "finished" else
               "run it again")
        return RunWriteError(err.path, err.reason, f"{kept}; {fix}, then {nxt}", err.code)


# ---------------------------------------------------------------------------------------- creating
def _is_run_entry(name: str) -> bool:
    return bool(_RUN_ENTRY.match(name))


def _clean_stale(parent: Path, name: str) -> None:
    """Remove new-run stages that a killed ``train`` left beside ``name`` (never one whose lock
    another process holds: it is being built)."""
    for stage in parent.glob(f".{glob_escape(name)}.new-*"):
        try:
            lock = lock_dir(stage, exclusive=True)
        except RunError:
            continue
        try:
            remove_tree(stage)
        finally:
            lock.release()


def glob_escape(text: str) -> str:
    return re.sub(r"([*?\[])", r"[\1]", text)


def check_target(path: PathLike, force: bool) -> bool:
    """Whether a new run may be created at ``path``: True when it replaces a run (``force``),
    False when the place is free (missing, or an empty directory). Anything else is refused with
    one sentence: a file, a directory that is not a run (whatever the flags), a run without
    ``force``. :func:`create_run` checks again under the lock."""
    target = Path(path).expanduser().resolve()
    if not (target.exists() or target.is_symlink()):
        return False
    if not target.is_dir():
        raise RunError(f"{shown(target)} is a file, not a run directory; choose another --out "
                       "(--force replaces only a run)")
    try:
        entries = sorted(e for e in os.listdir(target) if e != LOCK_FILE)
    except OSError as err:
        raise RunError(f"{shown(target)}: cannot be read ({_short(err)})") from None
    if not entries:
        return False
    if MANIFEST not in entries:
        raise RunError(f"{shown(target)} is a directory that is not a run (it has no {MANIFEST}); asapc never "
                       "replaces it, even with --force: choose another --out")
    foreign = [e for e in entries if not _is_run_entry(e)]
    if foreign:
        raise RunError(f"{shown(target)} holds files that are not part of a run ({shown(', '.join(foreign[:3]))}"
                       f"{', ...' if len(foreign) > 3 else ''}); asapc never replaces it, even with --force: "
                       "choose another --out")
    if not force:
        run = RunDir(target)
        try:
            how = f"continue it with `{run.command(run.read_manifest(), '--resume')}`, or replace it with --force"
        except RunError:
            how = "it is damaged: replace it with --force"
        raise RunError(f"{shown(target)} already holds a run; {how}")
    return True


def create_run(path: PathLike, manifest: Mapping[str, Any], source: str, *, force: bool,
               initial: Callable[[RunDir], None], interrupts=None, held: Optional[DirLock] = None) -> RunDir:
    """Create the run directory ``path`` whole, holding its exclusive lock.

    It is built in a hidden directory beside ``path`` (spec copy, manifest, then ``initial(run)``,
    which writes the step-0 checkpoint) and renamed into place. ``path`` may be missing or an
    empty directory; a run there is replaced only with ``force`` (exchanged with the new one,
    then removed), and anything else never (:func:`check_target`). ``held``: the exclusive lock
    of ``path`` when the caller took it already (it is released once the new run is in place).
    """
    target = Path(path).expanduser().resolve()
    replace = check_target(target, force)
    old: Optional[DirLock] = held
    if old is None and target.is_dir():  # nobody may use it while it is replaced
        old = lock_dir(target, exclusive=True, wait_hint="stop it first, or choose another --out")
    parent = target.parent
    with writing(parent):
        parent.mkdir(parents=True, exist_ok=True)
    _clean_stale(parent, target.name)
    with writing(parent):
        stage = Path(tempfile.mkdtemp(prefix=f".{target.name}.new-", dir=parent))
        os.chmod(stage, 0o777 & ~_UMASK)
    lock = lock_dir(stage, exclusive=True)
    try:
        staged = RunDir(stage)
        staged.lock, staged.interrupts = lock, interrupts
        atomic_write(staged.spec_path, source)
        staged.write_manifest(manifest)
        initial(staged)
        with (interrupts.critical("the new run") if interrupts is not None else nullcontext()):
            if replace:
                exchange(stage, target)
                remove_tree(stage)  # the replaced run, now under the stage's name
            else:
                if old is not None:  # an empty directory (perhaps with a lock file): renamed over
                    remove_tree(target / LOCK_FILE)
                with writing(target):
                    try:
                        os.rename(stage, target)
                    except OSError as err:
                        if err.errno in (errno.ENOTEMPTY, errno.EEXIST):  # another process created it just now
                            raise RunError(f"{shown(target)} already holds a run (created meanwhile by another "
                                           "process)") from None
                        raise
            fsync_dir(parent)
    except BaseException:
        remove_tree(stage)
        lock.release()
        raise
    finally:
        if old is not None:
            old.release()
    run = RunDir(target)
    lock.directory = target
    run.lock, run.interrupts = lock, interrupts
    return run


def stamp() -> str:
    """The time a manifest records (local, with its offset)."""
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")
