"""A run's summary: what a report reads of a finished run, without the weight of training it.

A finished run directory holds its manifest, its spec, its evaluation and its curves (a few
kilobytes), its best model (about a megabyte) and a checkpoint with the replay buffer (more). A
sweep of hours that must outlive the machine it runs on (a session, a CI job) keeps each
finished run's summary in a directory that is committed: the first four files, and where asked
the policy's actions on a few example states (``examples.json``: replayed through the rollout,
they redraw the policy's example trajectories without the model), and the policy's evaluations
refined by a look-ahead (``lookahead8-n1000.json``: ``asapc compare --lookahead`` adds them
after the run finished, so a report made from the summaries keeps its look-ahead row). ``asapc compare
--summaries DIR`` writes them as runs finish and copies them back into its runs before it plans:
a run read back from its summary is finished, never trained again, and its evaluation is still
checked against the manifest's record of its model.

A summary is copied whole or not at all: built in a hidden directory beside its name, then
renamed in (exchanged with an older copy of the same run).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Mapping, Optional, Union

from .runfiles import RunError, exchange, fsync_dir, remove_tree, shown, writing
from .runs import (CURVES, EVAL, EXAMPLES, LOOKAHEAD_FILE, MANIFEST, SPEC_COPY, RunDir, atomic_write_json,
                   read_json)

__all__ = ["SUMMARY_FILES", "add_to_summary", "is_summary", "read_examples", "restore_summaries", "save_summary"]

PathLike = Union[str, os.PathLike]

#: What a summary keeps of a run (and :data:`~asap_dsl.runs.EXAMPLES` where asked, and the
#: look-ahead's evaluations, :data:`~asap_dsl.runs.LOOKAHEAD`, where the run has them).
SUMMARY_FILES = (MANIFEST, SPEC_COPY, EVAL, CURVES)


def is_summary(run: RunDir, manifest: Mapping) -> bool:
    """A finished run whose model and checkpoint were left out (its summary only): it can be
    reported, not evaluated again or resumed. (A run that lost its model but kept its checkpoint
    is damaged, not a summary.)"""
    return (manifest["status"] == "finished" and manifest.get("model") is not None
            and not run.model_path.exists() and not run.checkpoint_dir.exists())


def save_summary(run_path: PathLike, dest: PathLike, examples: Optional[Mapping[str, Any]] = None) -> Path:
    """Copy the summary of the finished run at ``run_path`` into ``dest/<the run's directory
    name>``, replacing an older copy; returns that path. ``examples``: the policy's recorded
    ``states [K, n]`` and ``actions [K, steps, m]`` (NaN after each episode's end), kept beside it.
    Read under the run's shared lock; :class:`RunError` for a run that is not finished or whose
    files do not check out (its spec against the manifest's hash, its evaluation against its
    model's record)."""
    run = RunDir(run_path)
    dest = Path(dest).expanduser().resolve()
    target = dest / run.path.name
    with run.acquire(exclusive=False):
        manifest = run.read_manifest()
        if manifest["status"] != "finished":
            raise RunError(f"{shown(run.path)}: not finished (it is {run.status_text(manifest)}): no summary yet")
        run.read_spec()
        run.read_eval(manifest)
        sources = {n: run.path / n for n in SUMMARY_FILES if (run.path / n).exists()}
        sources.update({p.name: p for p in run.path.iterdir() if LOOKAHEAD_FILE.match(p.name)})
        with writing(dest):
            dest.mkdir(parents=True, exist_ok=True)
            stage = Path(tempfile.mkdtemp(prefix=f".{target.name}.new-", dir=dest))
            try:
                for name, src in sources.items():
                    shutil.copyfile(src, stage / name)
                    with open(stage / name, "rb") as f:
                        os.fsync(f.fileno())
                if examples is not None:
                    atomic_write_json(stage / EXAMPLES, {"model_sha256": manifest["model"]["sha256"],
                                                         **_recorded(examples)})
                fsync_dir(stage)
                if target.exists():
                    exchange(stage, target)
                else:
                    os.rename(stage, target)
                    fsync_dir(dest)
            finally:
                remove_tree(stage)
    return target


def add_to_summary(run_path: PathLike, dest: PathLike, name: str) -> Optional[Path]:
    """Copy the run's file ``name`` (a look-ahead's evaluation, made after the run's summary was
    kept) into its summary under ``dest``, atomically; None where the run has no summary there."""
    run = RunDir(run_path)
    target = Path(dest).expanduser().resolve() / run.path.name
    if not (target / MANIFEST).is_file():
        return None
    with run.acquire(exclusive=False):
        data = read_json(run.path / name, name)
    atomic_write_json(target / name, data)
    return target / name


def restore_summaries(source: PathLike, runs_dir: PathLike) -> list[Path]:
    """Copy each run summary under ``source`` into ``runs_dir`` where that run is missing (a run
    there, finished or not, is never touched); returns the runs copied. A missing ``source`` has
    none. Each is built in a hidden directory and renamed in, like a new run."""
    source, runs_dir = Path(source).expanduser().resolve(), Path(runs_dir).expanduser().resolve()
    if not source.is_dir():
        return []
    copied = []
    for entry in sorted(source.iterdir()):
        if entry.name.startswith(".") or not (entry / MANIFEST).is_file():
            continue
        target = runs_dir / entry.name
        if target.exists():
            continue
        with writing(runs_dir):
            runs_dir.mkdir(parents=True, exist_ok=True)
            stage = Path(tempfile.mkdtemp(prefix=f".{entry.name}.new-", dir=runs_dir))
            try:
                for f in entry.iterdir():
                    if f.is_file():
                        shutil.copyfile(f, stage / f.name)
                os.rename(stage, target)
                fsync_dir(runs_dir)
            finally:
                remove_tree(stage)
        copied.append(target)
    return copied


def read_examples(run: RunDir, manifest: Mapping) -> Optional[tuple[Any, list]]:
    """A summary's recorded examples as ``(states [K, n], [actions [steps, m] per state])``, the
    NaN rows after each end dropped; None when it has none, or when they were recorded from
    another model than the manifest's."""
    import numpy as np

    path = run.path / EXAMPLES
    if not path.is_file():
        return None
    data = read_json(path, "recorded examples")
    if data.get("model_sha256") != (manifest.get("model") or {}).get("sha256"):
        return None
    try:
        m = int(data["n_action"])
        return (np.asarray(data["states"], dtype=np.float64),
                [np.asarray(seq, dtype=np.float64).reshape(-1, m) for seq in data["actions"]])
    except (KeyError, TypeError, ValueError) as err:
        raise RunError(f"{shown(path)}: not recorded examples ({err})") from None


def _recorded(examples: Mapping[str, Any]) -> dict:
    """The states and each one's actions up to its episode's end (the first row that is not finite),
    as plain numbers: repr-exact floats, so that a replay takes the very same actions."""
    import numpy as np

    states = np.asarray(examples["states"], dtype=np.float64)
    actions = np.asarray(examples["actions"], dtype=np.float64)
    seqs = []
    for a in actions:
        bad = ~np.isfinite(a).all(axis=1)
        seqs.append(a[: int(np.argmax(bad)) if bad.any() else len(a)].tolist())
    return {"n_action": int(actions.shape[2]), "states": states.tolist(), "actions": seqs}
