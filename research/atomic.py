"""Atomic file writes: write to a temporary name in the same directory, then rename.

An interrupted run therefore never leaves a half-written file under the final
name. `os.replace` is atomic on POSIX when source and target share a filesystem,
which holds because the temporary file lives beside the target.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import tempfile
from pathlib import Path
from typing import Any, Iterator


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# The names atomic_path gives its temporary files: `.<stem>.<8 random characters>.tmp<ext>`
# (tempfile.mkstemp's random part is 8 characters of [a-z0-9_]).
_TEMP_NAME = re.compile(r"^\..*\.[a-z0-9_]{8}\.tmp(\.[^./]+)?$")


def is_temporary(name: str) -> bool:
    """Whether a file name is one of atomic_path's temporary names."""
    return bool(_TEMP_NAME.match(name))


def sweep_temporary(root: str | os.PathLike) -> list[Path]:
    """Delete atomic_path's temporary files under `root` (recursively); return what was deleted.

    Only a killed run leaves them (an exception removes its own), so call this at the start of a
    run that owns `root`, before it writes anything, never while another process writes there.
    """
    root = Path(root)
    if not root.is_dir():
        return []
    gone = []
    for p in root.rglob(".*"):
        if p.is_file() and not p.is_symlink() and is_temporary(p.name):
            with contextlib.suppress(FileNotFoundError):
                p.unlink()
                gone.append(p)
    return gone


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside `path`; rename it onto `path` on success.

    The temporary name keeps the target's extension (or `suffix`), because some
    writers (OpenImageIO) choose the file format from the extension. On any
    exception the temporary file is removed and the target is left untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ext = suffix if suffix is not None else "".join(path.suffixes[-1:])
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{ext}", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # mkstemp creates 0600 files; give the result the permissions a plain open() would.
        os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())


def write_text(path: str | os.PathLike, text: str) -> None:
    write_bytes(path, text.encode("utf-8"))


def write_json(path: str | os.PathLike, obj: Any) -> None:
    write_text(path, json.dumps(obj, indent=2, sort_keys=False) + "\n")
