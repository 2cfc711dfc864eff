"""A sweep's runs as tasks on a Ray cluster (``asapc compare --ray ADDRESS``).

The cluster is one a user started (``ray start --head --port 6379`` on one machine, ``ray start
--address HEAD:6379`` on the others; docs/compare.md): this process joins it as a driver, one task
per training run. Ray turns token authentication on by default: the head writes its token to
``~/.ray/auth_token``, and a driver that finds a token there (or in ``RAY_AUTH_TOKEN`` or
``RAY_AUTH_TOKEN_PATH``) presents it.

- **Failures.** A task whose worker or node dies is retried elsewhere (Ray's ``max_retries``); it
  resumes its run from the last checkpoint the manifest vouches for, so the report is the one a
  sweep without the fault writes. A run that fails for good is reported, not retried.
- **Reaching the cluster** is bounded: an address that is not one is refused at once, one that
  does not answer within ``timeout`` seconds is one sentence (:class:`ClusterError`), as is a
  token the cluster refuses.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import os
import re
import socket
import sys
import threading
from pathlib import Path
from typing import Callable, Sequence

__all__ = ["ClusterError", "connect", "execute_ray", "parse_address"]

#: how often a task is started again after its worker or node died
RETRIES = 3

_HOST = re.compile(r"^(?=.{1,253}$)[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?(?:\.[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*$")


class ClusterError(RuntimeError):
    """The Ray cluster cannot be used (unreachable, refused us, Ray missing): one sentence."""


def parse_address(text: str) -> str:
    """``auto``, ``local`` (a cluster of this process), ``HOST:PORT`` or ``ray://HOST:PORT``;
    ``ValueError`` with one sentence for anything else."""
    value = text.strip()
    if value in ("auto", "local"):
        return value
    rest = value[len("ray://"):] if value.startswith("ray://") else value
    host, sep, port = rest.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    ok_host = bool(host) and (bool(_HOST.match(host)) or _is_ip(host))
    if not (sep and ok_host and port.isdigit() and 0 < int(port) < 65536):
        raise ValueError(f"'{text}' is not a Ray address: give the head's HOST:PORT (as `ray start --head "
                         "--port PORT` printed it), ray://HOST:PORT, or auto")
    return value


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        return False


def _host_port(address: str) -> tuple[str, int]:
    rest = address[len("ray://"):] if address.startswith("ray://") else address
    host, _, port = rest.rpartition(":")
    return host.strip("[]"), int(port)


def _use_token() -> None:
    """Present the cluster's token when one is at hand and the mode was not chosen: what
    ``ray start`` does for the head, and Ray's driver does not do by itself. Ray reads the mode
    when it loads; if it is loaded already, its configuration is read again."""
    if os.environ.get("RAY_AUTH_MODE"):
        return
    path = os.environ.get("RAY_AUTH_TOKEN_PATH") or str(Path.home() / ".ray" / "auth_token")
    if not (os.environ.get("RAY_AUTH_TOKEN") or Path(path).is_file()):
        return
    os.environ["RAY_AUTH_MODE"] = "token"
    if "ray" in sys.modules:
        try:
            from ray._raylet import Config

            Config.initialize("")
        except (ImportError, AttributeError):  # another version of Ray: it reads the environment itself
            pass


def connect(address: str, timeout: float = 30.0) -> bool:
    """Join the cluster at ``address`` (``ray.init``) within ``timeout`` seconds; True when this
    call connected (the caller then disconnects). :class:`ClusterError` in one sentence."""
    address = parse_address(address)
    _use_token()
    try:
        import ray
    except ImportError:
        raise ClusterError("--ray needs Ray: pip install 'asap-dsl[ray]'") from None
    if ray.is_initialized():
        return False
    if address not in ("auto", "local"):
        host, port = _host_port(address)
        try:  # Ray itself would retry for minutes, printing its log: a plain probe first
            socket.create_connection((host, port), timeout=timeout).close()
        except OSError as err:
            why = "no answer" if isinstance(err, socket.timeout) else (err.strerror or str(err) or type(err).__name__)
            raise ClusterError(f"cannot reach a Ray cluster at {address} within {timeout:g} s ({why}); is "
                               "`ray start --head` running there?") from None
    outcome: dict = {}

    def init() -> None:
        try:
            ray.init(address=None if address == "local" else address, log_to_driver=False,
                     logging_level=logging.ERROR, include_dashboard=False, configure_logging=True)
        except BaseException as err:  # noqa: BLE001 — told in a sentence below
            outcome["error"] = err

    with _captured_stderr() as log:  # Ray's core logs each retry on stderr: kept, and read for the reason
        t = threading.Thread(target=init, name="ray-connect", daemon=True)
        if address == "local":  # in this thread: the local cluster's processes die with the thread that
            t.run()             # started them (PR_SET_PDEATHSIG), and there is nobody to wait for
        else:
            t.start()
            t.join(timeout)
        log.keep = t.is_alive()  # still retrying: its log goes on into the file, not onto the user's screen
    said = log.read()
    if "InvalidAuthToken" in said or "Unauthenticated" in said:
        raise ClusterError(f"the Ray cluster at {address} refused this driver's token: put the cluster's token in "
                           "~/.ray/auth_token, RAY_AUTH_TOKEN or RAY_AUTH_TOKEN_PATH")
    if t.is_alive():
        raise ClusterError(f"the Ray cluster at {address} did not accept this driver within {timeout:g} s")
    err = outcome.get("error")
    if err is not None:
        text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise ClusterError(f"cannot join the Ray cluster at {address}: {text[:300]}")
    return True


class _Log:
    def __init__(self, f):
        self.f, self.text, self.keep = f, "", False

    def read(self) -> str:
        if not self.f.closed:
            self.f.seek(0)
            self.text = self.f.read().decode("utf-8", "replace")
        return self.text


@contextlib.contextmanager
def _captured_stderr():
    """File descriptor 2 into a temporary file (Ray's C++ core writes there, not to sys.stderr)."""
    import tempfile

    f = tempfile.TemporaryFile()
    sys.stderr.flush()
    saved = os.dup(2)
    os.dup2(f.fileno(), 2)
    log = _Log(f)
    try:
        yield log
    finally:
        log.read()
        if log.keep:  # fd 2 stays in the file; this process's own messages go to the real stderr
            sys.stderr = os.fdopen(saved, "w", buffering=1)
        else:
            os.dup2(saved, 2)
            os.close(saved)
            f.close()


def execute_ray(jobs: Sequence, runs_dir: str, address: str, tell: Callable, timeout: float = 30.0) -> list[dict]:
    """Every job as a Ray task (one CPU each, retried where its worker or node died); the results
    in job order. Raises :class:`~.sweep.SweepInterrupted` after Ctrl-C or SIGTERM (the running
    tasks are cancelled: each training checkpoints)."""
    import ray

    from asap_dsl.processes import Interrupts

    from .sweep import SweepInterrupted, run_job

    connected = connect(address, timeout)
    try:
        remote = ray.remote(num_cpus=1, max_retries=RETRIES, retry_exceptions=False)(run_job)
        futures = {}
        for i, job in enumerate(jobs):
            futures[remote.remote(job, runs_dir)] = (i, job)
            tell("start", job, None)
        results: dict[int, dict] = {}
        pending = list(futures)
        stop = Interrupts()
        with stop:
            while pending and not stop.requested:
                ready, pending = ray.wait(pending, num_returns=1, timeout=0.5)
                for ref in ready:
                    i, job = futures[ref]
                    results[i] = _result(ray, ref, job)
                    tell("done", job, results[i])
            if stop.requested:
                for ref in pending:
                    ray.cancel(ref)
                for ref in pending:
                    i, job = futures[ref]
                    results[i] = _result(ray, ref, job, stopped=True)
                raise SweepInterrupted([results[i] for i in sorted(results)])
        return [results[i] for i in sorted(results)]
    finally:
        if connected:
            ray.shutdown()


def _result(ray, ref, job, stopped: bool = False) -> dict:
    """A task's result; a task that failed for good is a failed run (the sweep goes on), and one
    cancelled by a stop that does not answer within two minutes an interrupted one."""
    from .sweep import JobResult

    try:
        return ray.get(ref, timeout=120 if stopped else None)
    except Exception as err:  # noqa: BLE001 — told in the result
        if stopped:
            return JobResult(job, "", "interrupted").to_dict()
        text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        return JobResult(job, "", "failed", error=f"the Ray task failed after {RETRIES} retries ({type(err).__name__}: "
                         f"{text[:200]})").to_dict()
