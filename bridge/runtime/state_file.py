"""A node's saved state on disk: one small msgpack file per node, replaced atomically.

Each save writes a temporary file beside the real one, flushes and fsyncs it, renames it over
the old one and fsyncs the folder, so after a crash (``kill -9``, power loss) the file is the
old state or the new one, never a mix. The runtime saves before it carries out what depends on
the state (a publication, a report, a frame that uses a reserved counter), so a restart never
repeats or loses what the previous run made visible.

Large byte strings in the state (an image channel's pictures, up to 256 kB each) change
seldom while the rest changes with every frame, so each is kept in a file of its own named
by its SHA-256 (``….state.<digest>.blob``), written (durably) once, before the first state
that names it, and removed once a state that no longer names it is saved: a picture in
flight costs one write, not one at every save (three a second on seed 002's link).

One bridge at a time: :meth:`StateFile.hold` takes an ``flock`` on ``….state.lock`` for the
bridge's lifetime (the kernel lets it go when the process ends, however it ends), so a second
``zab run`` of the node on the same state directory stops at start instead of both saving
over each other.

A file that cannot be read or decoded, or that names a blob missing or altered, is moved
aside (``….corrupt``) with a warning, and the node starts afresh: its peers see a new epoch
and resynchronise.
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import logging
import os
import tempfile
from pathlib import Path
from typing import Any

import msgpack

from bridge.errors import ZabError
from bridge.wire.payloads import why_undecodable

log = logging.getLogger("zab.state")

BLOB_BYTES = 4096
"""Byte strings at least this long are kept in blob files of their own."""
BLOB_EXT = 1
"""The msgpack extension type that stands for a blob in the state file (its digest)."""


class StateError(ZabError):
    """The state directory cannot be used (not writable, not a directory)."""


def default_state_dir() -> Path:
    """systemd's ``$STATE_DIRECTORY`` (``StateDirectory=``), else the XDG state folder."""
    systemd = os.environ.get("STATE_DIRECTORY")
    if systemd:
        return Path(systemd.split(":")[0])
    base = os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state"
    return Path(base) / "zab"


class StateFile:
    """The saved state of one node of one mission under ``directory``."""

    def __init__(self, directory: str | Path, mission: str, node: str) -> None:
        self.path = Path(directory) / f"{mission}.{node}.state"
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StateError(f"cannot use the state directory {self.path.parent}: "
                             f"{exc.strerror or exc}") from None
        if not os.access(self.path.parent, os.W_OK):
            raise StateError(f"the state directory {self.path.parent} is not writable")
        self.saves = 0
        self.blobs: dict[str, bytes] = {}
        """The blobs the file on disk names, by digest."""
        self.lock_path = self.path.with_name(self.path.name + ".lock")
        self._held: int | None = None  # the lock file's descriptor while held

    def hold(self) -> None:
        """Hold the node's state for this process (until :meth:`release` or its end): an
        exclusive ``flock`` on :attr:`lock_path`, which holds this process's id. StateError
        if another process holds it."""
        if self._held is not None:
            return
        try:
            fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except OSError as exc:
            raise StateError(f"cannot open {self.lock_path}: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = _pid_in(fd)
            os.close(fd)
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise StateError(f"cannot lock {self.lock_path}: {exc.strerror or exc}"
                                 ) from None
            raise StateError(
                f"another bridge holds this node's state ({self.lock_path} is locked"
                f"{f' by process {holder}' if holder else ''}): stop it first, or give this "
                "one a --state-dir of its own") from None
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        except OSError:
            pass  # (the id is only said to a second bridge: the lock is what matters)
        self._held = fd

    def release(self) -> None:
        """Let another bridge take the node's state (the lock file stays)."""
        if self._held is not None:
            os.close(self._held)  # (closing the descriptor ends the flock)
            self._held = None

    def load(self) -> dict[str, Any] | None:
        """The last saved state, or None (none yet, or unreadable: moved aside)."""
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            self._remove_blobs_but({})  # (of a state moved aside as corrupt)
            return None
        except OSError as exc:
            log.warning("cannot read %s (%s): starting afresh", self.path, exc)
            return None
        named: dict[str, bytes] = {}
        try:
            state = msgpack.unpackb(data, raw=False, strict_map_key=False,
                                    ext_hook=lambda code, digest: self._read_blob(
                                        code, digest, named))
            if not isinstance(state, dict):
                raise ValueError("not a map")
        except (ValueError, msgpack.UnpackException) as exc:
            aside = self.path.with_name(self.path.name + ".corrupt")
            os.replace(self.path, aside)
            log.warning("%s is corrupt (%s): moved to %s, starting afresh", self.path,
                        why_undecodable(exc, data), aside)
            return None
        self.blobs = named
        self._remove_blobs_but(named)  # (left by a crash between a save and its clean-up)
        return state

    def _blob_path(self, digest: str) -> Path:
        return self.path.with_name(f"{self.path.name}.{digest}.blob")

    def _read_blob(self, code: int, digest: bytes, named: dict[str, bytes]) -> bytes:
        """The bytes a blob reference in the file stands for (ValueError: none, or altered)."""
        name = digest.hex()
        if code != BLOB_EXT:
            raise ValueError(f"unknown extension type {code}")
        try:
            data = self._blob_path(name).read_bytes()
        except OSError as exc:
            raise ValueError(f"its blob {name} cannot be read ({exc.strerror or exc})") from None
        if hashlib.sha256(data).hexdigest() != name:
            raise ValueError(f"its blob {name} was altered")
        named[name] = data
        return data

    def _remove_blobs_but(self, kept: dict[str, bytes]) -> None:
        for path in self.path.parent.glob(f"{self.path.name}.*.blob"):
            if path.name.split(".")[-2] not in kept:
                path.unlink(missing_ok=True)

    def save(self, state: dict[str, Any]) -> None:
        """Replace the saved state with ``state`` (atomic, durable)."""
        named: dict[str, bytes] = {}
        data = msgpack.packb(_with_references(state, named, self.blobs), use_bin_type=True)
        new = [digest for digest in named if digest not in self.blobs]
        for digest in new:
            self._write(self._blob_path(digest), named[digest])
        if new:  # (on disk before the state that names them)
            self._sync_folder()
        self._write(self.path, data)
        self._sync_folder()
        gone = self.blobs.keys() - named.keys()
        self.blobs = named
        for digest in gone:  # (no longer named by the state on disk)
            self._blob_path(digest).unlink(missing_ok=True)
        self.saves += 1

    def _sync_folder(self) -> None:
        folder = os.open(self.path.parent, os.O_RDONLY)
        try:
            os.fsync(folder)
        finally:
            os.close(folder)

    def _write(self, path: Path, data: bytes) -> None:
        """``data`` into ``path`` through a temporary file, flushed and fsynced."""
        fd, tmp = tempfile.mkstemp(prefix=self.path.name + ".", dir=self.path.parent)
        try:
            with os.fdopen(fd, "wb") as stream:
                stream.write(data)
                stream.flush()
                os.fsync(stream.fileno())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise


def lock_holder(directory: str | Path, mission: str, node: str) -> str | None:
    """Who holds the node's state lock (as :meth:`StateFile.hold` takes it): ``None`` when no
    process does, else ``"process <pid>"`` (or ``"another process"``). Only tries the lock,
    never creates the file; a lock free this instant is let go at once."""
    lock_path = Path(directory) / f"{mission}.{node}.state.lock"
    try:
        fd = os.open(lock_path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None  # no lock file (or none we may read): no bridge has run here
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
            return None
        holder = _pid_in(fd)
        return f"process {holder}" if holder else "another process"
    finally:
        os.close(fd)  # (and with it a lock this call took)
    return None


def _pid_in(fd: int) -> str:
    """The process id a lock file holds ('' if none can be read)."""
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        return ""
    return text if text.isdigit() else ""


def _with_references(value: Any, named: dict[str, bytes], known: dict[str, bytes]) -> Any:
    """``value`` with each large byte string replaced by a reference to its blob (collected
    in ``named`` by digest; ``known``: blobs on disk, whose digests are not computed again
    for the very same bytes)."""
    if isinstance(value, bytes | bytearray):
        if len(value) < BLOB_BYTES:
            return value
        digest = next((d for d, b in known.items() if b is value), None) or \
            hashlib.sha256(value).hexdigest()
        named[digest] = value if isinstance(value, bytes) else bytes(value)
        return msgpack.ExtType(BLOB_EXT, bytes.fromhex(digest))
    if isinstance(value, dict):
        return {k: _with_references(v, named, known) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_with_references(v, named, known) for v in value]
    return value
