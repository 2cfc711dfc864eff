"""What a run directory's files must be when they are read back (:mod:`asap_dsl.runs` reads them
through these checks): the manifest's schema, an evaluation that belongs to its run, curves that
are rows of numbers. Each failure is named in words a user can act on.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Union

from .runfiles import RunError, shown

__all__ = ["FORMAT_VERSION", "STATUSES", "check_manifest", "evaluation_problem", "read_curves"]

FORMAT_VERSION = 2
STATUSES = ("running", "interrupted", "finished", "failed")
_HEX64 = re.compile(r"^[0-9a-f]{64}$")
PathLike = Union[str, os.PathLike]


# ---------------------------------------------------------------------------------------- manifest
def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _is_record(x: Any) -> bool:
    return (isinstance(x, dict) and _is_int(x.get("size")) and x["size"] >= 0
            and isinstance(x.get("sha256"), str) and bool(_HEX64.match(x["sha256"])))


_FIELDS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "spec_file": (lambda v: isinstance(v, str) and os.path.isabs(v), "an absolute path"),
    "spec_hash": (lambda v: isinstance(v, str) and bool(_HEX64.match(v)), "a sha256"),
    "task": (lambda v: isinstance(v, str) and v != "", "a name"),
    "config": (lambda v: isinstance(v, dict), "an object"),
    "versions": (lambda v: isinstance(v, dict), "an object"),
    "status": (lambda v: v in STATUSES, " or ".join(STATUSES)),
    "steps_done": (lambda v: _is_int(v) and v >= 0, "a whole number"),
    "seconds": (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and v >= 0, "a number"),
    "created": (lambda v: isinstance(v, str), "a date"),
}
_OPTIONAL: dict[str, tuple[Callable[[Any], bool], str]] = {
    "best": (lambda v: v is None or isinstance(v, dict), "an object"),
    "model": (lambda v: v is None or _is_record(v), "a file record (size, sha256)"),
    "checkpoint": (lambda v: v is None or (isinstance(v, dict) and _is_int(v.get("steps")) and v["steps"] >= 0
                                           and isinstance(v.get("files"), dict) and bool(v["files"])
                                           and all(isinstance(k, str) and re.match(r"^[\w.-]+$", k) and k not in (".", "..")
                                                   and _is_record(r) for k, r in v["files"].items())),
                   "a checkpoint record"),
    "error": (lambda v: v is None or isinstance(v, str), "a sentence"),
}


def check_manifest(data: Any, where: PathLike) -> dict:
    """``data`` if it is a manifest of this version, else :class:`RunError` naming what is wrong."""
    def damaged(what: str) -> RunError:
        return RunError(f"{shown(where)}: damaged manifest ({what}); replace the run with `asapc train ... --force`")

    if not isinstance(data, dict):
        raise damaged("not a JSON object")
    fmt = data.get("format")
    if fmt != FORMAT_VERSION:
        if _is_int(fmt) and 0 < fmt < FORMAT_VERSION:
            raise RunError(f"{shown(where)}: written by an older asap-dsl (run format {fmt}); "
                           "train it again with `asapc train ... --force`")
        raise damaged(f"format {fmt!r}, expected {FORMAT_VERSION}")
    for table, required in ((_FIELDS, True), (_OPTIONAL, False)):
        for key, (ok, kind) in table.items():
            if key not in data:
                if required:
                    raise damaged(f"no '{key}'")
                continue
            if not ok(data[key]):
                raise damaged(f"'{key}' is {_preview(data[key])}, expected {kind}")
    return data


def _preview(value: Any) -> str:
    text = json.dumps(value, default=str)
    return shown(text if len(text) <= 40 else text[:37] + "...")


# ---------------------------------------------------------------------------------------- eval.json, curves.csv
def evaluation_problem(data: Any, manifest: Mapping[str, Any]) -> Optional[str]:
    """Why ``data`` (an ``eval.json``) is not an evaluation of this run's spec and best model, or
    None when it is."""
    if not isinstance(data, dict):
        return "not an evaluation"
    rows, per_state, episodes = data.get("rows"), data.get("per_state"), data.get("episodes")
    if not (_is_int(episodes) and episodes > 0 and isinstance(rows, list) and rows and all(
            isinstance(r, dict) and _is_int(r.get("tolerance")) and _is_int(r.get("count"))
            and isinstance(r.get("rate"), (int, float)) and isinstance(r.get("ci95"), list) for r in rows)):
        return "damaged (its rows or episode count are not an evaluation's)"
    if not (isinstance(per_state, dict) and isinstance(per_state.get("t_reach"), list)
            and len(per_state["t_reach"]) == episodes):
        return "damaged (its per-state results are missing or cut)"
    if data.get("spec_hash") != manifest["spec_hash"]:
        return "it evaluated another spec than the run's"
    model = manifest.get("model")
    if model is None or data.get("model_sha256") != model["sha256"]:
        return "it evaluated another model than the run's best"
    return None


def read_curves(path: PathLike) -> list[dict]:
    """``curves.csv`` as rows of numbers by column ([] when there is none yet); :class:`RunError`
    naming the line that is not one."""
    import csv

    path = Path(path)
    if not path.exists():
        return []
    try:
        with open(path, newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise RunError(f"{shown(path)}: unreadable training curves ({_short(err)})") from None
    out = []
    for i, row in enumerate(rows, 2):
        try:
            # an empty cell: a column the run did not keep yet when that row was written (return)
            values = {k: float(v) for k, v in row.items() if v != ""}
        except (TypeError, ValueError):
            raise RunError(f"{shown(path)}: line {i} is not a row of numbers (damaged)") from None
        if "steps" not in values or not all(math.isfinite(v) for v in values.values()):
            raise RunError(f"{shown(path)}: line {i} is not a row of curves (damaged)")
        out.append(values)
    return out


def _short(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return text[0] if text else type(err).__name__
