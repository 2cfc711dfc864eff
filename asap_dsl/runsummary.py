"""A run's summary: what a report reads of a finished run, without the weight of training it.

A finished run directory holds its manifest, its spec, its evaluation and its curves (a few
kilobytes), its best model, and a checkpoint with the replay buffer (megabytes). A sweep of
hours that must outlive the machine it runs on (a session, a CI job) keeps each finished run's
summary in a directory that is committed: the first four files, and the model only where asked
(the run a report draws its example trajectories from). ``asapc compare --summaries DIR`` writes
them as runs finish and copies them back into its runs before it plans: a run read back from its
summary is finished, never trained again, and its evaluation is still checked against the
manifest's record of its model.

A summary is copied whole or not at all: built in a hidden directory beside its name, then
renamed in (exchanged with an older copy of the same run).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Mapping, Union

from .runfiles import RunError, exchange, fsync_dir, remove_tree, shown, writing
from .runs import CURVES, EVAL, MANIFEST, MODEL, SPEC_COPY, RunDir

__all__ = ["SUMMARY_FILES", "is_summary", "restore_summaries", "save_summary"]

PathLike = Union[str, os.PathLike]

#: What a summary keeps of a run (and :data:`~asap_dsl.runs.MODEL` where asked).
SUMMARY_FILES = (MANIFEST, SPEC_COPY, EVAL, CURVES)


def is_summary(run: RunDir, manifest: Mapping) -> bool:
    """A finished run whose model was left out (its summary only): it can be reported, not
    evaluated again or resumed."""
    return manifest["status"] == "finished" and manifest.get("model") is not None and not run.model_path.exists()


def save_summary(run_path: PathLike, dest: PathLike, model: bool = False) -> Path:
    """Copy the summary of the finished run at ``run_path`` (with its model when ``model``) into
    ``dest/<the run's directory name>``, replacing an older copy; returns that path. Read under
    the run's shared lock; :class:`RunError` for a run that is not finished or whose files do not
    check out (its spec against the manifest's hash, its evaluation against its model's record)."""
    run = RunDir(run_path)
    dest = Path(dest).expanduser().resolve()
    target = dest / run.path.name
    with run.acquire(exclusive=False):
        manifest = run.read_manifest()
        if manifest["status"] != "finished":
            raise RunError(f"{shown(run.path)}: not finished (it is {run.status_text(manifest)}): no summary yet")
        run.read_spec()
        run.read_eval(manifest)
        names = [n for n in SUMMARY_FILES if (run.path / n).exists()]
        sources = {n: run.path / n for n in names}
        if model:
            sources[MODEL] = run.model_file(manifest)
        with writing(dest):
            dest.mkdir(parents=True, exist_ok=True)
            stage = Path(tempfile.mkdtemp(prefix=f".{target.name}.new-", dir=dest))
            try:
                for name, src in sources.items():
                    shutil.copyfile(src, stage / name)
                    with open(stage / name, "rb") as f:
                        os.fsync(f.fileno())
                fsync_dir(stage)
                if target.exists():
                    exchange(stage, target)
                else:
                    os.rename(stage, target)
                    fsync_dir(dest)
            finally:
                remove_tree(stage)
    return target


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
