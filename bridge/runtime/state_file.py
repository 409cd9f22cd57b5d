"""A node's saved state on disk: one small msgpack file per node, replaced atomically.

Each save writes a temporary file beside the real one, flushes and fsyncs it, renames it over
the old one and fsyncs the folder, so after a crash (``kill -9``, power loss) the file is the
old state or the new one, never a mix. The runtime saves before it carries out what depends on
the state (a publication, a report, a frame that uses a reserved counter), so a restart never
repeats or loses what the previous run made visible.

A file that cannot be read or decoded is moved aside (``….corrupt``) with a warning, and the
node starts afresh: its peers see a new epoch and resynchronise.
"""

from __future__ import annotations

import logging
import os
import tempfile
from pathlib import Path
from typing import Any

import msgpack

from bridge.errors import ZabError

log = logging.getLogger("zab.state")


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

    def load(self) -> dict[str, Any] | None:
        """The last saved state, or None (none yet, or unreadable: moved aside)."""
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            return None
        except OSError as exc:
            log.warning("cannot read %s (%s): starting afresh", self.path, exc)
            return None
        try:
            state = msgpack.unpackb(data, raw=False, strict_map_key=False)
            if not isinstance(state, dict):
                raise ValueError("not a map")
        except (ValueError, msgpack.UnpackException) as exc:
            aside = self.path.with_name(self.path.name + ".corrupt")
            os.replace(self.path, aside)
            log.warning("%s is corrupt (%s): moved to %s, starting afresh", self.path, exc,
                        aside)
            return None
        return state

    def save(self, state: dict[str, Any]) -> None:
        """Replace the saved state with ``state`` (atomic, durable)."""
        data = msgpack.packb(state, use_bin_type=True)
        fd, tmp = tempfile.mkstemp(prefix=self.path.name + ".", dir=self.path.parent)
        try:
            with os.fdopen(fd, "wb") as stream:
                stream.write(data)
                stream.flush()
                os.fsync(stream.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        folder = os.open(self.path.parent, os.O_RDONLY)
        try:
            os.fsync(folder)
        finally:
            os.close(folder)
        self.saves += 1
