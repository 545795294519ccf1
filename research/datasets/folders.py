"""The folders of a dataset being written: `--out` checks, `.partial` state, the --force swap, locks.

A dataset is written into `<out>.partial/` (its configuration recorded first in
`.drlab-partial.json`) and renamed to `<out>` when complete; `--force` swaps an old dataset out
through `<out>.drlab-old`; `<out>.lock` serialises processes preparing the same dataset. See
research/datasets/generate.py for the whole sequence.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
import sys
import threading
from pathlib import Path
from typing import Any

from research.datasets.config import is_config_record
from research.datasets.integrity import GENERATOR, MANIFEST

PARTIAL_CONFIG = ".drlab-partial.json"


def commit(out: Path, partial: Path) -> None:
    """Rename the finished `partial` to `out`; with --force the old dataset is renamed aside first.

    A kill between the renames leaves `<out>.drlab-old`, which the next run puts back or deletes
    (`recover_swap`); the finished `.partial` still holds its manifest, so `--force --resume`
    completes it without rendering (plain `--force` starts over).
    """
    (partial / PARTIAL_CONFIG).unlink(missing_ok=True)  # the manifest records the configuration from here on
    if out.is_dir() and not out.is_symlink() and not any(out.iterdir()):
        out.rmdir()
    if out.exists() or out.is_symlink():
        old = _old_dir(out)
        os.replace(out, old)
        os.replace(partial, out)
        if old.is_symlink():  # --out was a link to a dataset: drop the link, keep what it pointed to
            old.unlink()
        else:
            shutil.rmtree(old)
    else:
        os.replace(partial, out)


def partial_state(partial: Path, cfg_dict: dict[str, Any], resume: bool, force: bool) -> str:
    """"none", "resume", "unreadable" or "force" (the last two: replace it); ValueError when the user must decide."""
    if not partial.exists():
        return "none"
    recorded = partial_config(partial)
    if recorded is None:
        return "unreadable"
    if force and not resume:
        return "force"
    if not resume:
        raise ValueError(f"--resume: an interrupted run left {partial}; pass --resume to finish it, or delete that "
                         "folder")
    if recorded != cfg_dict:
        raise ValueError(f"--resume: {partial} was started with a different configuration "
                         f"({config_diff(recorded, cfg_dict)}); delete that folder or rerun with its settings")
    return "resume"


def partial_dir(out: Path) -> Path:
    return out.with_name(out.name + ".partial")


def _old_dir(out: Path) -> Path:
    return out.with_name(out.name + ".drlab-old")


def notice(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _holds_dataset(path: Path) -> bool:
    """Whether `path` is a directory with a manifest.json written by drlab's generator."""
    try:
        m = json.loads((path / MANIFEST).read_text())
    except (OSError, ValueError):
        return False
    return isinstance(m, dict) and m.get("generator") == GENERATOR


def partial_config(partial: Path) -> dict[str, Any] | None:
    """The configuration a `.partial` folder was started with; None when missing or unreadable.

    A run killed after writing its manifest (but before the final rename) has already removed the
    configuration record; the manifest's copy counts then.
    """
    for name, key in ((PARTIAL_CONFIG, None), (MANIFEST, "config")):
        try:
            doc = json.loads((partial / name).read_text())
        except (OSError, ValueError):
            continue
        doc = doc.get(key) if key and isinstance(doc, dict) else doc
        if is_config_record(doc):
            return doc
    return None


def config_diff(recorded: dict[str, Any], wanted: dict[str, Any]) -> str:
    diff = [f"{k} {recorded.get(k)!r} there, {v!r} now" for k, v in wanted.items() if recorded.get(k) != v]
    return "; ".join(diff) or "same settings"


def check_out(out: str | Path, *, force: bool) -> Path:
    """`--out` checked before anything is created: a directory path whose parent can be written, not a
    file, and (unless empty) replaced only with `force` and only when it holds a drlab dataset."""
    if not isinstance(out, (str, os.PathLike)) or not str(out).strip():
        raise ValueError(f"--out: expected a directory path, got {out!r}")
    out = Path(out)
    if out.name in ("", ".", ".."):
        raise ValueError(f"--out: expected a path that names the dataset directory, got {str(out)!r}")
    if out.name.endswith(".partial") or out.name.endswith(".drlab-old") or out.name.endswith(".lock"):
        raise ValueError(f"--out: names ending in .partial, .drlab-old or .lock are drlab's own, got {out.name!r}")
    if (out.exists() or out.is_symlink()) and not out.is_dir():
        raise ValueError(f"--out: {out} is a file (or a broken link); expected a dataset directory")
    partial = partial_dir(out)
    if (partial.exists() or partial.is_symlink()) and not partial.is_dir():
        raise ValueError(f"--out: {partial} is a file, and drlab keeps the unfinished dataset there; move it away")
    anc = out.absolute().parent
    while not anc.exists():
        anc = anc.parent
    if not anc.is_dir():
        raise ValueError(f"--out: {anc} is a file, so {out} cannot be created")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise ValueError(f"--out: cannot create {out}: no write permission in {anc}")
    if out.is_dir() and any(out.iterdir()):
        if not force:
            raise ValueError(f"--out: {out} already exists; pass --force to replace it (only a drlab dataset is "
                             "replaced)")
        if not _holds_dataset(out):
            raise ValueError(f"--out: {out} does not hold a drlab dataset (no manifest.json written by drlab "
                             "dataset); --force replaces only datasets, so nothing was touched")
    return out


def recover_swap(out: Path) -> None:
    """Finish what a run killed during the --force swap left: put the old dataset back or delete it."""
    old = _old_dir(out)
    if not old.is_dir() or not _holds_dataset(old):
        return
    if out.exists():
        shutil.rmtree(old)
    else:
        os.replace(old, out)
        notice(f"note: restored {out} from {old}, left by a run killed while replacing it")


_locks = threading.local()


@contextlib.contextmanager
def dataset_lock(out: Path):
    """An exclusive fcntl.flock on `<out>.lock` (kept beside the dataset), re-entrant within a thread.

    Another process preparing the same dataset waits here (with a one-line notice) and then sees the
    finished dataset. The lock file stays: deleting it would let a third process lock a new file.
    """
    path = out.absolute().with_name(out.name + ".lock")
    held = _locks.__dict__.setdefault("held", {})
    key = str(path)
    if held.get(key):
        held[key] += 1
        try:
            yield
        finally:
            held[key] -= 1
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            notice(f"note: waiting for another process preparing {out} (lock {path})")
            fcntl.flock(fd, fcntl.LOCK_EX)
        held[key] = 1
        try:
            yield
        finally:
            held.pop(key, None)
    finally:
        os.close(fd)  # releases the lock
