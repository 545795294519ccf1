"""Checking a dataset directory against the SHA-256 hashes in its manifest.json (`verify`).

`verify(root)` checks that manifest.json was written by drlab's generator, that its content hash
agrees with the file hashes it lists, that every listed file exists with that hash, and that the
directory holds no other file. It returns the verified content hash, which is what experiments
record as the dataset's provenance.

Fast path: after a successful check, the size, mtime and ctime of every file are remembered in a
sidecar `.drlab-verified.json` inside the dataset (written atomically; not part of the content
hash, keyed by the manifest's own hash). The next check rehashes only the files whose size or
times changed. Any write to a file changes its mtime and ctime, so an edited file is always
rehashed; a dataset on a read-only filesystem is simply rehashed every time.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from pathlib import Path
from typing import Any

from research import atomic

MANIFEST = "manifest.json"
VERIFIED = ".drlab-verified.json"  # the fast path's cache (not content)
GENERATOR = "drlab dataset"  # manifest["generator"] of every dataset drlab writes
_HEX64 = re.compile(r"^[0-9a-f]{64}$")


class DatasetError(ValueError):
    """A dataset on disk is missing files or holds inconsistent data."""


def read_or_fail(reader, path: Path):
    """`reader(path)`, with a missing file or a ValueError turned into a one-line DatasetError naming `path`."""
    try:
        return reader(path)
    except FileNotFoundError:
        raise DatasetError(f"{path}: missing") from None
    except ValueError as e:
        text = " ".join(str(e).split())  # one line, whatever the decoder said
        raise DatasetError(text if text.startswith(str(path)) else f"{path}: {text}") from None


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def content_hash(files: dict[str, str]) -> str:
    """SHA-256 over the sorted (relative path, file hash) pairs."""
    h = hashlib.sha256()
    for rel in sorted(files):
        h.update(f"{rel}\0{files[rel]}\n".encode())
    return h.hexdigest()


def is_sidecar(name: str) -> bool:
    """drlab's own bookkeeping files inside a dataset: the verification cache and its temporary names."""
    return name == VERIFIED or (atomic.is_temporary(name) and name.startswith(VERIFIED.removesuffix(".json") + "."))


def read_manifest(root: Path) -> tuple[dict[str, Any], bytes]:
    """manifest.json of a drlab dataset, parsed and checked for shape, and its raw bytes."""
    path = root / MANIFEST
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise DatasetError(f"{path}: missing (not a drlab dataset, or an unfinished one)") from None
    except OSError as e:
        raise DatasetError(f"{path}: cannot be read ({e.strerror})") from None
    try:
        m = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(m, dict) or m.get("generator") != GENERATOR:
        raise DatasetError(f"{path}: not a manifest written by drlab dataset")
    files = m.get("files")
    if not isinstance(files, dict) or not files or not all(
            isinstance(k, str) and isinstance(v, str) and _HEX64.match(v) for k, v in files.items()):
        raise DatasetError(f"{path}: 'files' must map relative paths to SHA-256 hex digests")
    for rel in files:
        parts = Path(rel).parts
        if Path(rel).is_absolute() or ".." in parts or not parts or rel == MANIFEST or is_sidecar(parts[-1]):
            raise DatasetError(f"{path}: 'files' lists {rel!r}, which is not a file inside the dataset")
    if m.get("content_hash") != content_hash(files):
        raise DatasetError(f"{path}: content_hash does not match the file hashes it lists (the manifest was edited)")
    return m, raw


def _stat_key(p: Path) -> list[int]:
    st = p.stat()
    return [st.st_size, st.st_mtime_ns, st.st_ctime_ns]


def write_cache(root: Path, manifest_raw: bytes, hashes: dict[str, str]) -> None:
    """Remember the current size and times of files whose hashes were just checked (best effort)."""
    doc = {"manifest_sha256": hashlib.sha256(manifest_raw).hexdigest(),
           "files": {rel: _stat_key(root / rel) + [h] for rel, h in sorted(hashes.items())}}
    try:
        atomic.write_json(root / VERIFIED, doc)
    except OSError:  # a read-only dataset: no fast path, every check rehashes
        pass


def _read_cache(root: Path, manifest_raw: bytes) -> dict[str, list]:
    try:
        doc = json.loads((root / VERIFIED).read_text())
        if doc.get("manifest_sha256") == hashlib.sha256(manifest_raw).hexdigest() and isinstance(doc["files"], dict):
            return doc["files"]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        pass
    return {}


def verify(root: str | Path) -> str:
    """Check the dataset at `root` against its manifest (see module docstring); its content hash.

    Raises DatasetError naming the first file that is missing, changed or not listed.
    """
    root = Path(root)
    m, raw = read_manifest(root)
    files: dict[str, str] = m["files"]
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames.sort()
        for name in sorted(filenames):
            p = Path(dirpath) / name
            rel = p.relative_to(root).as_posix()
            if rel == MANIFEST or rel == VERIFIED:
                continue
            if Path(dirpath) == root and is_sidecar(name):
                # A cache write killed half-way. Deleting it is safe even if a live process is writing
                # it: write_cache ignores the OSError that process then gets.
                p.unlink(missing_ok=True)
                continue
            if rel not in files:
                raise DatasetError(f"{p}: not listed in manifest.json (a file added after the dataset was written)")
    cache = _read_cache(root, raw)
    checked: dict[str, str] = {}
    changed = False
    for rel in sorted(files):
        p = root / rel
        if not p.is_file():
            raise DatasetError(f"{p}: listed in manifest.json but missing")
        key = _stat_key(p)
        if cache.get(rel) != key + [files[rel]]:
            changed = True
            if file_sha256(p) != files[rel]:
                raise DatasetError(f"{p}: content does not match its SHA-256 in manifest.json "
                                   "(the file changed after the dataset was written)")
        checked[rel] = files[rel]
    if changed or set(cache) != set(files):
        write_cache(root, raw, checked)
    return m["content_hash"]
