"""The file-level guarantees a run directory is built on (:mod:`asap_dsl.runs` uses them):

- **atomic writes**: a file is written to a temporary beside it, synced, and renamed into place,
  so a kill leaves the old version or the new one, never half of one; a directory is replaced by
  exchanging it with a complete new one (``renameat2(RENAME_EXCHANGE)``);
- **write failures in one sentence**: a full disk, a read-only or unwritable directory, an I/O
  error (``ENOSPC``, ``EROFS``, ``EACCES``, ``EIO``, ...) become :class:`RunWriteError`, naming
  the path and the reason, after the partial file is removed;
- **records**: a file's size and sha256, written into a manifest when the file is written and
  checked when it is read, so that a damaged or swapped file is refused;
- **locks**: ``fcntl.flock`` on a lock file in a directory, exclusive for a writer, shared for
  readers, held as long as the process needs it (the kernel drops it when the process dies, so
  a lock is never stale); a refusal names the process that holds it;
- **commands a user can paste**: arguments shell-quoted, control characters escaped.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import fcntl
import gc
import hashlib
import os
import re
import shlex
import shutil
import tempfile
import traceback
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Optional, Sequence, Union

__all__ = ["DirLock", "RunBusy", "RunError", "RunWriteError", "atomic_path", "atomic_write", "command_line",
           "exchange", "file_record", "lock_dir", "record_mismatch", "remove_tree", "shell_quote", "shown",
           "writing"]

PathLike = Union[str, os.PathLike]
LOCK_FILE = ".lock"

_UMASK = os.umask(0)
os.umask(_UMASK)


class RunError(Exception):
    """A run directory that cannot be used as asked (missing, damaged, in use, from another spec,
    unwritable). Its message is one plain sentence for the user."""


class RunBusy(RunError):
    """Another process holds the directory's lock; ``pid`` is that process (None if unknown)."""

    def __init__(self, message: str, pid: Optional[int] = None):
        super().__init__(message)
        self.pid = pid


class RunWriteError(RunError):
    """A write that failed (disk full, read-only, no permission, I/O error): ``path`` and
    ``reason`` say which and why; the partial file has been removed."""

    def __init__(self, path: PathLike, reason: str, detail: Optional[str] = None, code: Optional[int] = None):
        super().__init__(f"cannot write {shown(path)}: {reason}" + (f" ({detail})" if detail else ""))
        self.path, self.reason, self.code = Path(path), reason, code

    @property
    def remedy(self) -> str:
        """What the user can do about it, in a few words."""
        if self.code in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
            return "free some space"
        if self.code in (errno.EROFS, errno.EACCES, errno.EPERM):
            return "make it writable"
        if self.code == errno.EIO:
            return "check the disk"
        return "fix that"


# The errors of a write that the user can fix (space, permissions, the medium), as opposed to a bug.
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO,
                          errno.EFBIG, errno.ENAMETOOLONG, errno.ENOTDIR, errno.EISDIR, errno.ENOENT,
                          errno.EEXIST, errno.ENOTEMPTY, errno.EMLINK, errno.ELOOP, errno.EBUSY, errno.ETXTBSY})


def _reason(err: OSError) -> str:
    text = err.strerror or os.strerror(err.errno or 0) or type(err).__name__
    return text[0].lower() + text[1:] if text else "unknown error"


def is_write_error(err: BaseException) -> bool:
    return isinstance(err, OSError) and err.errno in WRITE_ERRNOS


@contextmanager
def writing(path: PathLike, exact: bool = False) -> Iterator[None]:
    """Turn a failed write of ``path`` into :class:`RunWriteError`, naming the file the OS names
    (or ``path`` itself with ``exact``: a temporary's name would tell the user nothing)."""
    try:
        yield
        return
    except RunWriteError:
        raise
    except OSError as err:
        if not is_write_error(err):
            raise
        target = path if exact else (err.filename or path)
        reason = _reason(err)
        if err.errno in (errno.EEXIST, errno.ENOTDIR):  # a file where a directory of the path should be
            blocker = _file_in_the_way(path)
            if blocker is not None:
                reason = f"{shown(blocker)} is a file, not a directory"
        failure = RunWriteError(target, reason, code=err.errno)
        # The writer's frames hold its open file: let it go, so that removing the partial file
        # frees the space (a full disk must have room for the manifest's "failed" afterwards).
        traceback.clear_frames(err.__traceback__)
        del err
        gc.collect()
    raise failure from None


def _file_in_the_way(path: PathLike) -> Optional[Path]:
    """The nearest existing parent of ``path`` that is no directory (``plots/x.png`` where
    ``plots`` is a file: mkdir says "file exists", which tells the user nothing)."""
    for parent in Path(path).parents:
        if parent.exists() or parent.is_symlink():
            return None if parent.is_dir() else parent
    return None


def shown(path: PathLike) -> str:
    """A path as a message prints it: control characters escaped (``\\x1b``), nothing else changed."""
    from .diagnostics import printable

    return printable(str(path))


# ---------------------------------------------------------------------------------- atomic writes
def fsync_dir(directory: PathLike) -> None:
    """Make a rename in ``directory`` durable (best effort: some file systems refuse)."""
    try:
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path`` atomically.

    For writers that want a file name (``model.save``). On any exception the temporary is removed
    and ``path`` is left as it was; a failed write is :class:`RunWriteError`.
    """
    path = Path(path)
    with writing(path, exact=True):
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + "".join(path.suffixes[-1:]),
                                   dir=path.parent)
        os.close(fd)
    tmp_path = Path(tmp)
    try:
        with writing(path, exact=True):
            os.chmod(tmp_path, 0o666 & ~_UMASK)  # mkstemp makes 0600; a run's files are as readable as any other
        yield tmp_path
        with writing(path, exact=True):
            with open(tmp_path, "rb+") as f:  # the data is on disk before the name points at it
                os.fsync(f.fileno())
            os.replace(tmp_path, path)
        fsync_dir(path.parent)
    finally:
        try:
            tmp_path.unlink()
        except OSError:
            pass


def atomic_write(path: PathLike, data: Union[str, bytes]) -> None:
    """Write ``data`` to ``path`` atomically (text as UTF-8)."""
    raw = data.encode("utf-8") if isinstance(data, str) else data
    with atomic_path(path) as tmp:
        with writing(path, exact=True):
            tmp.write_bytes(raw)


def remove_tree(path: PathLike) -> None:
    """Remove a file or directory tree if it exists; never raises (what is left is reported by
    whoever needs the space)."""
    p = Path(path)
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        try:
            p.unlink()
        except OSError:
            pass


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _renameat2():
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    fn.restype = ctypes.c_int
    return fn


_EXCHANGE = _renameat2()


def exchange(a: PathLike, b: PathLike) -> None:
    """Swap two directories atomically (each name then holds the other's tree). Where the kernel
    or file system cannot (no ``RENAME_EXCHANGE``), ``b`` is moved aside and ``a`` renamed in:
    the name is missing only between two renames."""
    a, b = Path(a), Path(b)
    with writing(b):
        if _EXCHANGE is not None:
            if _EXCHANGE(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
                fsync_dir(b.parent)
                return
            code = ctypes.get_errno()
            if code not in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
                raise OSError(code, os.strerror(code), str(b))
        aside = Path(tempfile.mkdtemp(prefix=f".{b.name}.aside-", dir=b.parent))
        os.rmdir(aside)
        os.rename(b, aside)
        try:
            os.rename(a, b)
        except OSError:
            os.rename(aside, b)
            raise
        os.rename(aside, a)
        fsync_dir(b.parent)


# ---------------------------------------------------------------------------------- records
def file_record(path: PathLike) -> dict:
    """``{"size", "sha256"}`` of a file, as a manifest stores it."""
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
            size += len(block)
    return {"size": size, "sha256": h.hexdigest()}


def record_mismatch(path: PathLike, record: dict) -> Optional[str]:
    """Why ``path`` is not the file ``record`` describes (missing, another size, another hash), or
    None when it is."""
    p = Path(path)
    try:
        size = p.stat().st_size
    except FileNotFoundError:
        return "it is missing"
    except OSError as err:
        return f"it cannot be read ({_reason(err)})"
    if not p.is_file():
        return "it is not a regular file"
    if size != record.get("size"):
        return f"it has {size:,} bytes where {record.get('size'):,} were written"
    try:
        digest = file_record(p)["sha256"]
    except OSError as err:
        return f"it cannot be read ({_reason(err)})"
    if digest != record.get("sha256"):
        return "its content is not what was written (sha256 differs)"
    return None


# ---------------------------------------------------------------------------------- locks
class DirLock:
    """A held ``flock`` on ``<directory>/.lock`` (exclusive or shared); :meth:`release` drops it,
    as does the end of the process. The file descriptor is close-on-exec and never inherited by
    spawned processes."""

    def __init__(self, directory: Path, exclusive: bool, fd: Optional[int]):
        self.directory, self.exclusive, self._fd = directory, exclusive, fd

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        if self._fd is not None:
            fd, self._fd = self._fd, None
            try:
                fcntl.flock(fd, fcntl.LOCK_UN)
            finally:
                os.close(fd)

    def __enter__(self) -> "DirLock":
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def __del__(self):  # pragma: no cover - a lock dropped without release()
        try:
            self.release()
        except Exception:  # noqa: BLE001 — interpreter shutdown
            pass


def _proc_lock_holders(st: os.stat_result) -> list[int]:
    """PIDs that hold a flock on the file of ``st``, from /proc/locks (Linux)."""
    key = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    out = []
    try:
        with open("/proc/locks", encoding="ascii", errors="replace") as f:
            for line in f:
                parts = line.split()
                if "->" in parts:  # a waiter, not a holder
                    continue
                if len(parts) >= 6 and parts[1] == "FLOCK" and parts[5] == key and parts[4].isdigit():
                    out.append(int(parts[4]))
    except OSError:
        pass
    return [p for p in out if p != os.getpid()]


def _process_text(pid: int) -> str:
    try:
        raw = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return ""
    args = [a.decode("utf-8", "replace") for a in raw.split(b"\0") if a]
    for i, a in enumerate(args):  # "python -m asap_dsl.cli train ..." reads as "asapc train ..."
        if a == "asap_dsl.cli" or a.endswith("/asapc"):
            args = ["asapc"] + args[i + 1:]
            break
    text = " ".join(args)
    return shown(text if len(text) <= 80 else text[:77] + "...")


def holder(directory: PathLike) -> Optional[int]:
    """The process holding ``directory``'s lock, if one does (None if it is free or unknown)."""
    path = Path(directory) / LOCK_FILE
    try:
        st = path.stat()
    except OSError:
        return None
    pids = _proc_lock_holders(st)
    if pids:
        return pids[0]
    try:
        text = path.read_text(encoding="ascii").strip()
        return int(text) if text.isdigit() else None
    except (OSError, ValueError, UnicodeDecodeError):
        return None


def busy_message(directory: PathLike, pid: Optional[int], what: str) -> str:
    if pid is None:
        return f"{shown(directory)} is in use by another process; wait for it to finish, then run this again"
    text = _process_text(pid)
    who = f"process {pid}" + (f" ({text})" if text else "")
    return f"{shown(directory)} is in use by {who}; {what}"


def lock_dir(directory: PathLike, exclusive: bool, *, wait_hint: str = "wait for it to finish, or stop it, "
             "then run this again") -> DirLock:
    """Take ``directory``'s lock without waiting: exclusive for a writer, shared for readers.

    Raises :class:`RunBusy` naming the holder when another process has it in a conflicting mode.
    A shared lock on a directory that cannot hold a lock file (read-only) is granted without one:
    nobody can be writing there. The lock file may have been replaced (a directory exchanged by
    ``--force``) between opening and locking it; then the new one is taken.
    """
    directory = Path(directory)
    path = directory / LOCK_FILE
    for _ in range(20):
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666 & ~_UMASK)
        except OSError as err:
            if exclusive or err.errno not in (errno.EROFS, errno.EACCES, errno.EPERM):
                raise RunWriteError(path, _reason(err), code=err.errno) from None
            try:
                fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
            except OSError:
                return DirLock(directory, False, None)
        try:
            fcntl.flock(fd, (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH) | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            pid = holder(directory)
            raise RunBusy(busy_message(directory, pid, wait_hint), pid) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if not same:  # the directory was exchanged under us: lock the one now at this name
            os.close(fd)
            continue
        if exclusive:  # the holder, for systems without /proc/locks
            try:
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            except OSError:
                pass
        return DirLock(directory, exclusive, fd)
    raise RunBusy(busy_message(directory, None, wait_hint))


# ---------------------------------------------------------------------------------- commands
_SAFE = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def shell_quote(arg: Union[str, os.PathLike]) -> str:
    """One argument as a POSIX shell reads it back: ``shlex.quote``, or ``$'...'`` with escapes
    where it holds control characters (printing those raw would drive the terminal, and the
    pasted command would not name the same file)."""
    text = os.fspath(arg)
    if not _SAFE.search(text):
        return shlex.quote(text)
    out = []
    for ch in text:
        if ch == "\\":
            out.append("\\\\")
        elif ch == "'":
            out.append("\\'")
        elif _SAFE.match(ch):
            out.append(f"\\x{ord(ch):02x}" if ord(ch) < 0x80 else f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return "$'" + "".join(out) + "'"


def command_line(args: Sequence[Union[str, os.PathLike]]) -> str:
    """A command to paste into a shell: every argument quoted as :func:`shell_quote` does."""
    return " ".join(shell_quote(a) for a in args)
