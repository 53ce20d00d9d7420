"""Content-addressed cache of stage outputs, written atomically.

An entry, ``<cache>/<stage>/<key>/``, holds the stage's outputs and an
``entry.json`` (stage, version, parameters, input fingerprints, output
checksums, metrics).  The key is the SHA-256 of everything that determines
the result: stage name and version, parameters with their defaults, the
configuration values the stage declares, and the SHA-256 of every input (an
upstream re-run that made the same bytes is still a hit).  Entries are built
in a temporary folder and renamed in after ``entry.json``; every checksum is
verified on reuse (a damaged entry is recomputed, never used).  Runs sharing
a cache hold a ``flock`` per entry while they look it up or compute it; a
killed run's workspace is removed by the next run holding its key's lock.
Nothing under the cache root is followed as a symbolic link: a stage folder
that is a link, a file or cannot be written, or a lock that is a folder, is
set aside (``.damaged-*`` in the cache root; a link is removed, never its
target) with a warning, and the stage is recomputed.
No pickle: entries are plain files and JSON.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import logging
import os
import shutil
import stat
import tempfile
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline.errors import FULL, UNWRITABLE, EnvironmentFailure, InputDataError

if TYPE_CHECKING:
    from pydantic import BaseModel

ENTRY_FILE = "entry.json"
#: Prefix of the name under which a damaged part of the cache is set aside, in the cache root.
DAMAGED = ".damaged-"
META_SUM = "entry_sha256"  # checksum of entry.json's other fields
_CHUNK = 1 << 20
UMASK = os.umask(0)
os.umask(UMASK)


def cache_root(config: BaseModel) -> Path:
    cache = getattr(config, "cache", None)
    return Path(cache) if cache else Path(config.output) / ".cache"


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


def file_kind(mode: int) -> str:
    """What a file of mode *mode* (``st_mode``) is, in words: "a folder", "a FIFO (named pipe)"..."""
    kinds = (
        (stat.S_ISREG, "a regular file"),
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISLNK, "a symbolic link"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    )
    return next((words for test, words in kinds if test(mode)), "not a regular file")


def identity(st: os.stat_result) -> tuple[int, ...]:
    """What tells one version of a file from another: device, inode, size, mtime and ctime."""
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)


class NotRegularFile(OSError):
    """A path that should name a regular file names something else (``strerror`` says what)."""


def hash_regular_file(path: Path, tries: int = 3) -> tuple[str, tuple[int, ...]]:
    """SHA-256 (hex) of the regular file *path*, and its :func:`identity` while it was read.

    A FIFO, a device or a folder is refused (:class:`NotRegularFile`) without
    being read: it is opened non-blocking and checked with ``fstat`` before a
    byte is read.  A file whose identity changes while it is read is read
    again; one that keeps changing is an :class:`~pipeline.errors.InputDataError`.
    """
    for _ in range(tries):
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
        with os.fdopen(fd, "rb", buffering=0) as fh:
            before = os.fstat(fd)
            if not stat.S_ISREG(before.st_mode):
                raise NotRegularFile(errno.EINVAL, file_kind(before.st_mode), str(path))
            digest = hashlib.sha256()
            while chunk := fh.read(_CHUNK):
                digest.update(chunk)
            if identity(os.fstat(fd)) == identity(before) == identity(os.stat(path)):
                return digest.hexdigest(), identity(before)
    raise InputDataError(f"{path}: the file kept changing while it was read; run again once it is no longer written.")


def folder_failure(side: str, folder: Path, exc: OSError) -> str:
    """The sentence for the *side*'s *folder* ("cache", "output") that is full or cannot be written."""
    then = "then run again: complete stages are reused."
    if exc.errno in FULL:
        return f"the {side} folder {folder} is full ({exc.strerror}); free space or point `{side}:` elsewhere, {then}"
    return (
        f"the {side} folder {folder} cannot be written ({exc.strerror or exc}); make it writable or point "
        f"`{side}:` elsewhere, {then}"
    )


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
        os.chmod(tmp, 0o666 & ~UMASK)  # mkstemp creates 0600; give the usual mode
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def exclusive_lock(path: Path, on_wait: Any = None):
    """Hold an exclusive ``flock`` on *path* (created if needed) for the block.

    ``on_wait()`` is called once if another process holds the lock and this
    one has to wait.  The lock is released by the kernel when its holder dies,
    so a killed run never leaves a lock behind.  (POSIX only: the pipeline
    runs on Linux and macOS; ``fcntl`` saves a dependency for these lines.)
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = open_lock_file(path)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if on_wait is not None:
                on_wait()
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock


def open_lock_file(path: Path) -> int:
    """Open (creating it if needed) the lock file *path*, never through a symbolic link.

    The pipeline never makes a lock file a link: one found in its place was
    planted, and following it would create or open a file outside the
    output and cache folders.  It is removed (the link, not what it points
    to) with a warning, and a plain lock file is made.  Other errors (a
    folder that cannot be written) are raised as they are.
    """
    for _ in range(3):
        try:
            return os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o666 & ~UMASK)
        except OSError as exc:
            if exc.errno != errno.ELOOP:
                raise
            logging.getLogger("pipeline").warning("%s is a symbolic link, not a lock file; removing the link", path)
            with contextlib.suppress(FileNotFoundError):
                os.unlink(path)
    raise OSError(errno.ELOOP, "a symbolic link keeps reappearing in place of a lock file", str(path))


def _is_locked(path: Path) -> bool:
    """Whether a live process holds the lock file *path*."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_NOFOLLOW)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return False
    except BlockingIOError:
        return True
    finally:
        os.close(fd)


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

    def __init__(self, root: Path, log: logging.Logger | logging.LoggerAdapter | None = None):
        self.root = Path(root)
        self.log = log or logging.getLogger(__name__)

    def entry_folder(self, stage: str, key: str) -> Path:
        return self.root / stage / key

    def stage_folder(self, stage: str) -> Path:
        """``<cache>/<stage>``, made a real folder: a link or a file in its place is set aside first."""
        folder = self.root / stage
        try:
            mode = os.lstat(folder).st_mode
        except FileNotFoundError:
            mode = None
        if mode is not None and not stat.S_ISDIR(mode):
            self.set_aside(folder, f"it is {file_kind(mode)}, not a folder")
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise self.unwritable(folder.parent, exc) from None
        return folder

    def set_aside(self, path: Path, why: str, cause: OSError | None = None) -> None:
        """Move the damaged *path* out of the way, with one warning; a link is removed, never its target.

        A file or folder is renamed to ``.damaged-*`` in the cache root, kept
        for inspection (deleting it is safe).  When even that fails (a
        read-only mount), :class:`~pipeline.errors.EnvironmentFailure` names
        *path* and the *cause* that made it damaged (else the failure itself).
        """
        try:
            if path.is_symlink():
                path.unlink()
                self.log.warning("the cache's %s is damaged (%s); removed the link, not its target", path, why)
                return
            flat = path.relative_to(self.root).as_posix().replace("/", "_").lstrip(".")
            aside = self.root / f"{DAMAGED}{flat}-{time.strftime('%Y%m%dT%H%M%S')}-{uuid.uuid4().hex[:6]}"
            os.rename(path, aside)
        except FileNotFoundError:
            return  # a concurrent run set it aside first
        except OSError as exc:
            raise self.unwritable(path, cause or exc) from None
        self.log.warning("the cache's %s is damaged (%s); set aside as %s, it is recomputed", path, why, aside)

    def unwritable(self, folder: Path, exc: OSError) -> EnvironmentFailure:
        """The exit-4 error for a cache *folder* that cannot be written (or a full disk under it)."""
        return EnvironmentFailure(folder_failure("cache", folder, exc))

    @contextlib.contextmanager
    def lock(self, stage: str, key: str, on_wait: Any = None) -> Iterator[None]:
        """Hold the exclusive lock of one entry (see :func:`exclusive_lock`).

        The stage folder is checked first (see :meth:`stage_folder`); a lock
        that is a folder, or a stage folder in which the lock cannot be
        created, is set aside once and made again.
        """
        for attempt in range(2):
            path = self.stage_folder(stage) / f".{key}.lock"
            try:
                if os.path.isdir(path) and not os.path.islink(path):
                    self.set_aside(path, "the lock is a folder, not a file")
                os.close(open_lock_file(path))
                break
            except OSError as exc:
                if exc.errno not in UNWRITABLE or attempt:
                    raise self.unwritable(path.parent, exc) from None
                self.set_aside(path.parent, f"it cannot be written: {exc.strerror}", exc)
        with exclusive_lock(path, on_wait):
            yield

    def lookup(self, stage: str, key: str, verify: bool = True, warn: bool = True) -> Entry | None:
        """The complete, undamaged entry for *key*, or None.

        An entry whose ``entry.json`` or any output fails its size or SHA-256
        check is reported with a warning (unless ``warn`` is False) and
        treated as missing (the caller recomputes it).  ``verify=False``
        checks sizes only.  An entry written before entries carried their own
        checksum is recomputed with a note, not a warning.
        """
        folder = self.entry_folder(stage, key)
        if folder.parent.is_symlink() or not folder.parent.is_dir():
            return None  # never read through a link; the stage folder is set aside before it is written
        if folder.is_symlink() or (os.path.lexists(folder) and not folder.is_dir()):
            kind = "a symbolic link" if folder.is_symlink() else "a file"
            return self._damaged(stage, key, f"the entry is {kind}, not a folder", warn)
        if not (folder / ENTRY_FILE).exists():
            return None
        try:
            meta = json.loads((folder / ENTRY_FILE).read_text(encoding="utf-8"))
            if isinstance(meta, dict) and "outputs" in meta and META_SUM not in meta:
                if warn:
                    self.log.info("cache entry %s/%s predates entry checksums; recomputing it", stage, key[:12])
                return None
            expected = meta.pop(META_SUM)
            outputs = meta["outputs"]
            files = [(out["file"], out["bytes"], out["sha256"]) for out in outputs.values()]
        except (OSError, ValueError, KeyError, TypeError, AttributeError, RecursionError):
            return self._damaged(stage, key, f"{ENTRY_FILE} is unreadable", warn)
        if hash_value(meta) != expected:
            return self._damaged(stage, key, f"{ENTRY_FILE} fails its checksum", warn)
        if meta.get("key", key) != key:
            return self._damaged(stage, key, f"{ENTRY_FILE} belongs to another key", warn)
        for name, size, digest in files:
            target = folder / name
            if not target.is_relative_to(folder) or ".." in Path(name).parts or not target.exists():
                return self._damaged(stage, key, f"{name} is missing", warn)
            if target.is_symlink():  # never followed out of the cache
                return self._damaged(stage, key, f"{name} is a symbolic link", warn)
            if path_size(target) != size:
                return self._damaged(stage, key, f"{name} has {path_size(target)} bytes, not {size}", warn)
            if verify and hash_path(target) != digest:
                return self._damaged(stage, key, f"{name} fails its SHA-256 checksum", warn)
        return Entry(folder, meta)

    def _damaged(self, stage: str, key: str, why: str, warn: bool) -> None:
        if warn:
            self.log.warning("cache entry %s/%s is damaged (%s); it will be recomputed", stage, key[:12], why)
        return None

    def new_workspace(self, stage: str, key: str = "") -> Path:
        """A fresh temporary folder in which a stage writes its outputs.

        Workspaces of killed runs (their key's lock is free) are removed.  A
        stage folder that cannot be written is set aside once and made again.
        """
        for attempt in range(2):
            parent = self.stage_folder(stage)
            try:
                self.sweep(stage, key)
                return Path(tempfile.mkdtemp(prefix=f".tmp-{key}-", dir=parent))
            except OSError as exc:
                if exc.errno not in UNWRITABLE or attempt:
                    raise self.unwritable(parent, exc) from None
                self.set_aside(parent, f"it cannot be written: {exc.strerror}", exc)
        raise AssertionError("unreachable")

    def sweep(self, stage: str, held: str) -> int:
        """Remove the workspaces killed runs left in *stage*'s folder.

        A workspace ``.tmp-<key>-*`` is dead when no live process holds its
        key's lock (a run holds it for as long as it computes the entry); those
        of *held*, the key whose lock the caller holds, are dead too (a lock
        held by this process looks taken to ``_is_locked``).  Returns how many
        were removed.
        """
        removed = 0
        folder = self.root / stage
        if folder.is_symlink() or not folder.is_dir():
            return 0  # never swept through a link (see stage_folder)
        for old in folder.glob(".tmp-*"):
            old_key = old.name[len(".tmp-") :].rsplit("-", 1)[0]
            if old_key and (old_key == held or not _is_locked(folder / f".{old_key}.lock")):
                _remove_path(old)
                removed += 1
        if removed:
            self.log.info("removed %d workspace(s) of killed runs from the cache of %s", removed, stage)
        return removed

    def commit(
        self,
        stage: str,
        key: str,
        workspace: Path,
        meta: dict[str, Any],
        replace: bool = False,
        known: dict[Path, str] | None = None,
    ) -> Entry:
        """Record checksums, write ``entry.json`` and move the workspace into place.

        An intact entry already there (a concurrent run finished first) is kept
        and the workspace discarded, unless *replace* (``--force``: the caller
        holds the key's lock and asked for the stage to be computed again).
        *known*: the SHA-256 of the stage's input files; an output that is one
        of them (a hard link: the same file) takes its checksum, not read again.
        """
        same = {}
        for path, digest in (known or {}).items():
            with contextlib.suppress(OSError):
                st = os.stat(path)
                if stat.S_ISREG(st.st_mode):
                    same[(st.st_dev, st.st_ino)] = digest
        outputs = {}
        for artifact, file_name in meta["outputs"].items():
            target = workspace / file_name
            if not target.exists():
                raise FileNotFoundError(f"stage {stage} did not write its output '{artifact}' ({file_name})")
            st = os.lstat(target)
            digest = same.get((st.st_dev, st.st_ino)) if stat.S_ISREG(st.st_mode) else None
            outputs[artifact] = {"file": file_name, "sha256": digest or hash_path(target), "bytes": path_size(target)}
        meta = {**meta, "outputs": outputs, "key": key, "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        meta = json.loads(json.dumps(meta, default=str))  # the form it will be read back in
        text = json.dumps({**meta, META_SUM: hash_value(meta)}, indent=2, sort_keys=True)
        atomic_write_text(workspace / ENTRY_FILE, text)
        final = self.entry_folder(stage, key)
        # Fully verified: an entry that fails its checksums is replaced, never kept.
        existing = None if replace else self.lookup(stage, key, verify=True, warn=False)
        if existing is not None:
            # Same key, same content: a concurrent run finished first; keep its entry.
            self.discard(workspace)
            return existing
        if os.path.lexists(final):  # damaged, or an incomplete leftover of a killed run
            _remove(final, workspace.parent / f".tmp-{key}-old-{uuid.uuid4().hex[:8]}")
        os.replace(workspace, final)
        return Entry(final, meta)

    @staticmethod
    def discard(workspace: Path) -> None:
        shutil.rmtree(workspace, ignore_errors=True)


def _sweep_tiles(folder: Path) -> None:
    """Remove the temporary folders that runs killed while keeping a tile left in *folder*.

    ``.tmp-<pid>-*`` of a process that no longer exists (a reused pid only
    delays the removal); ``.tmp-old-*`` are damaged entries set aside.
    """
    for old in folder.glob(".tmp-*"):
        pid = old.name.split("-")[1]
        if pid.isdigit():
            try:
                os.kill(int(pid), 0)
                continue
            except ProcessLookupError:
                pass
            except PermissionError:  # alive, another user's
                continue
        _remove_path(old)


def _remove_path(path: Path) -> None:
    """Remove a file, a symbolic link (never what it points to) or a folder."""
    if path.is_symlink() or not path.is_dir():
        path.unlink(missing_ok=True)
    else:
        shutil.rmtree(path, ignore_errors=True)


def _remove(path: Path, aside: Path) -> None:
    """Remove a file, a symbolic link (not its target) or a folder.

    A folder is first renamed to *aside* (a workspace name the next sweep
    removes if this run is killed), so the entry's name is free at once.
    """
    if path.is_symlink() or not path.is_dir():
        path.unlink()
        return
    os.replace(path, aside)
    shutil.rmtree(aside, ignore_errors=True)


#: Name of the record of a tile entry (:class:`TileCache`).
TILE_RECORD = "tile.json"


class TileCache:
    """Results of single tiles of a tiled stage, kept from one run to the next.

    A stage's entry (:class:`Cache`) is keyed by its whole input, so one
    changed input file re-runs every tile.  This keeps each tile's result
    under ``<cache>/tiles/<stage>/<kk>/<key>/``, the key made of *base*
    (the stage's name, version and settings, without its input) and what the
    tile's task read (:meth:`key`): a tile whose points did not change is
    found again, whatever else changed.  An entry holds the files the stage
    chose to keep and ``tile.json`` (the task's JSON result and every file's
    SHA-256, checked on reuse: a damaged entry is recomputed).  Entries are
    made in a temporary folder and renamed in; a link anywhere on the way is
    never followed (the tile is recomputed, and not kept).  ``--force`` of
    the stage (*reuse* False) recomputes every tile and keeps the results.
    """

    def __init__(self, root: Path, stage: str, base: Any, reuse: bool = True, log: Any = None):
        self.root = Path(root)
        self.folder = self.root / "tiles" / stage
        self.base = hash_value(base)
        self.reuse = reuse
        self.log = log or logging.getLogger(__name__)
        self.warned = False

    def key(self, material: Any) -> str:
        """The key of a tile whose task read *material* (JSON-ready; file contents as their SHA-256)."""
        return hash_value({"stage": self.base, "tile": material})

    def _entry(self, key: str) -> Path | None:
        """``<folder>/<kk>/<key>``, its parents made; None when one of them is not a real folder (never followed)."""
        path = self.root
        path.mkdir(parents=True, exist_ok=True)
        for part in ("tiles", self.folder.name, key[:2]):
            path = path / part
            with contextlib.suppress(FileExistsError):
                path.mkdir()  # (made by a concurrent run, or something else in its place: checked below)
            mode = os.lstat(path).st_mode
            if not stat.S_ISDIR(mode):
                if not self.warned:
                    self.log.warning("%s is %s, not a folder: tiles are not kept there", path, file_kind(mode))
                    self.warned = True
                return None
        return path / key

    def get(self, key: str) -> tuple[Path, Any] | None:
        """The folder and JSON result of the intact entry *key*; None when there is none (or reuse is off)."""
        return self.get_intact(key) if self.reuse else None

    def get_intact(self, key: str) -> tuple[Path, Any] | None:
        """The folder and JSON result of the entry *key* if it is intact, whatever *reuse* says."""
        folder = self._lookup_folder(key)
        if folder is None:
            return None
        try:
            fd = os.open(folder / TILE_RECORD, os.O_RDONLY | os.O_NOFOLLOW)
            with os.fdopen(fd, encoding="utf-8") as fh:
                record = json.load(fh)
            for name, digest in record["files"].items():
                path = folder / name
                if "/" in name or path.is_symlink() or not path.is_file() or hash_path(path) != digest:
                    raise ValueError(f"{name} is missing or damaged")
            return folder, record["result"]
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError) as exc:
            self.log.warning("tile entry %s is damaged (%s); it will be recomputed", key[:12], exc)
            return None

    def _lookup_folder(self, key: str) -> Path | None:
        path = self.folder / key[:2] / key
        for part in (self.folder.parent, self.folder, path.parent, path):
            try:
                if not stat.S_ISDIR(os.lstat(part).st_mode):
                    return None
            except FileNotFoundError:
                return None
        return path

    def put(self, key: str, fill: Any) -> None:
        """Keep a tile's result: ``fill(folder)`` writes its files into a new folder and returns its JSON result.

        Failing to keep a tile (a full disk, a folder that cannot be
        written) costs only its reuse: one warning, and the run goes on.
        """
        try:
            final = self._entry(key)
            if final is None:
                return
            if os.path.lexists(final):
                if self.get_intact(key) is not None:
                    return  # kept already (by a concurrent run, or before a --force)
                _remove(final, final.parent / f".tmp-old-{uuid.uuid4().hex[:8]}")  # damaged: replaced
            _sweep_tiles(final.parent)
            tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{os.getpid()}-", dir=final.parent))
            try:
                result = fill(tmp)
                files = {p.name: hash_path(p) for p in sorted(tmp.iterdir()) if p.is_file()}
                record = {"result": json.loads(canonical_json(result)), "files": files}
                atomic_write_text(tmp / TILE_RECORD, json.dumps(record, sort_keys=True))
                try:
                    os.rename(tmp, final)
                except OSError as exc:
                    if exc.errno not in (errno.EEXIST, errno.ENOTEMPTY):
                        raise
                    shutil.rmtree(tmp, ignore_errors=True)  # kept meanwhile by a concurrent run: the same tile
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
        except OSError as exc:
            if not self.warned:
                self.log.warning("tiles cannot be kept in %s (%s); this run goes on", self.folder, exc.strerror or exc)
                self.warned = True
