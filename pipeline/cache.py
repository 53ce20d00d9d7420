"""Content-addressed cache of stage outputs, written atomically.

An entry lives in ``<cache>/<stage>/<key>/``: the stage's output files and an
``entry.json`` (stage, version, parameters, input fingerprints, output
checksums, metrics).  The key is the SHA-256 of the canonical JSON of
everything that determines the result: stage name and version, parameters
with their defaults, the configuration values the stage declares, and the
SHA-256 of every input.  Because inputs are fingerprinted by content, a stage
whose upstream re-ran but produced identical bytes is still a cache hit.

Entries are built in a temporary folder beside their final place and renamed
into it as a whole, after ``entry.json`` is written: a killed run never leaves
an entry that a later run would trust.  Nothing here uses pickle: entries are
plain files and JSON.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ENTRY_FILE = "entry.json"
_CHUNK = 1 << 20
_UMASK = os.umask(0)
os.umask(_UMASK)


def canonical_json(value: Any) -> str:
    """JSON with sorted keys and no whitespace: equal values, equal text."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=True, default=str)


def hash_value(value: Any) -> str:
    """SHA-256 (hex) of the canonical JSON of *value*."""
    return hashlib.sha256(canonical_json(value).encode("ascii")).hexdigest()


def hash_path(path: Path) -> str:
    """SHA-256 (hex) of a file, or of a folder's relative names and file contents."""
    path = Path(path)
    if path.is_dir():
        digest = hashlib.sha256()
        for child in sorted(p for p in path.rglob("*") if p.is_file()):
            digest.update(child.relative_to(path).as_posix().encode("utf-8") + b"\0")
            digest.update(hash_path(child).encode("ascii"))
        return digest.hexdigest()
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def path_size(path: Path) -> int:
    path = Path(path)
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def atomic_write_text(path: Path, text: str) -> None:
    """Write a text file via a temporary file in the same folder and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp creates 0600; give the usual mode
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_copy(src: Path, dst: Path) -> None:
    """Copy a file or folder to *dst* through a temporary name and a rename."""
    dst = Path(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.parent / f".{dst.name}.{uuid.uuid4().hex[:8]}.tmp"
    try:
        if Path(src).is_dir():
            shutil.copytree(src, tmp)
            if dst.is_dir():
                shutil.rmtree(dst)
        else:
            shutil.copyfile(src, tmp)
        os.replace(tmp, dst)
    except BaseException:
        if tmp.is_dir():
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            tmp.unlink(missing_ok=True)
        raise


@dataclass
class Entry:
    """A complete cache entry."""

    folder: Path
    meta: dict[str, Any]

    def output_path(self, artifact: str) -> Path:
        return self.folder / self.meta["outputs"][artifact]["file"]

    def output_hash(self, artifact: str) -> str:
        return self.meta["outputs"][artifact]["sha256"]


class Cache:
    """The cache folder of one configuration."""

    def __init__(self, root: Path):
        self.root = Path(root)

    def entry_folder(self, stage: str, key: str) -> Path:
        return self.root / stage / key

    def lookup(self, stage: str, key: str) -> Entry | None:
        """The complete entry for *key*, or None (missing or incomplete)."""
        folder = self.entry_folder(stage, key)
        try:
            meta = json.loads((folder / ENTRY_FILE).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        for out in meta.get("outputs", {}).values():
            target = folder / out["file"]
            if not target.exists() or path_size(target) != out["bytes"]:
                return None
        return Entry(folder, meta)

    def new_workspace(self, stage: str) -> Path:
        """A fresh temporary folder in which a stage writes its outputs."""
        parent = self.root / stage
        parent.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=".tmp-", dir=parent))

    def commit(self, stage: str, key: str, workspace: Path, meta: dict[str, Any]) -> Entry:
        """Record checksums, write ``entry.json`` and move the workspace into place."""
        outputs = {}
        for artifact, file_name in meta["outputs"].items():
            target = workspace / file_name
            if not target.exists():
                raise FileNotFoundError(f"stage {stage} did not write its output '{artifact}' ({file_name})")
            outputs[artifact] = {"file": file_name, "sha256": hash_path(target), "bytes": path_size(target)}
        meta = {**meta, "outputs": outputs, "key": key, "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        atomic_write_text(workspace / ENTRY_FILE, json.dumps(meta, indent=2, sort_keys=True, default=str))
        final = self.entry_folder(stage, key)
        existing = self.lookup(stage, key)
        if existing is not None:
            # Same key, same content: a concurrent run finished first; keep its entry.
            self.discard(workspace)
            return existing
        if final.exists():  # an incomplete leftover of a killed run
            shutil.rmtree(final)
        os.replace(workspace, final)
        return Entry(final, meta)

    @staticmethod
    def discard(workspace: Path) -> None:
        shutil.rmtree(workspace, ignore_errors=True)
