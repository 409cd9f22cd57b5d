"""Exception tree of the bridge.

    ZabError
     ├── MissionError        the mission file is wrong (names file, line, column, field path)
     ├── LayoutError         a field list / codec layout is wrong (``loc`` says where in it)
     ├── EncodeError         a value cannot be encoded (missing field, wrong type, rejected range)
     ├── DecodeError         untrusted bytes cannot be decoded: the ONE error decoders raise
     │    └── FrameError     ... a whole acoustic frame (truncated, corrupt, foreign mission)
     ├── BackendError        a modem backend failed to load, open or operate
     │    └── SendTooLate    ... a frame dropped: its MAC turn ended before it could go out
     ├── SessionError        the Zenoh session cannot open (a port taken, a router unreachable)
     ├── WaterError          the simulated water cannot listen (its port taken or invalid)
     └── NodeFailure         a running node cannot go on (one of its tasks or threads failed)
"""

from __future__ import annotations


class ZabError(Exception):
    """Base class of every error the bridge raises on purpose."""


class MissionError(ZabError):
    """The mission file is invalid; the message is ready to show to a user."""


class LayoutError(ZabError, ValueError):
    """A field specification or codec layout is invalid.

    ``loc`` is the path inside the field list (e.g. ``(2, "bits")``) so that a caller
    that knows where the list came from (the mission loader) can point at the line.
    """

    def __init__(self, message: str, loc: tuple[str | int, ...] = ()) -> None:
        super().__init__(message)
        self.loc = loc


class EncodeError(ZabError, ValueError):
    """A value could not be encoded: missing field, wrong type, or out of range with ``reject``."""


class DecodeError(ZabError, ValueError):
    """Bytes could not be decoded. The only exception a decoder raises for any input."""


class FrameError(DecodeError):
    """An acoustic frame is truncated, corrupt, forged, replayed or from another mission file.

    ``reason`` names the drop counter: ``check`` (corrupt, or another mission file), ``forged``,
    ``replayed`` or ``malformed``. A failed check also gives the ``fingerprint`` (16 bits) the
    frame was sent with, so a receiver can tell another mission file from corruption.
    """

    def __init__(self, message: str, reason: str = "malformed",
                 fingerprint: int | None = None) -> None:
        super().__init__(message)
        self.reason = reason
        self.fingerprint = fingerprint


class BackendError(ZabError):
    """A modem backend could not be loaded, opened, or failed while running."""


class SendTooLate(BackendError):
    """A frame was not sent because the MAC turn it was granted ended first (the ``until`` of
    :meth:`~bridge.modems.base.ModemBackend.send`): too late to begin, or to retry after a
    failed try. A counted drop (the backend's ``stats["late"]``), not a modem failure: the
    backend stays up."""


class SessionError(ZabError):
    """The node's Zenoh session could not be opened; the message is one line for a user."""


class WaterError(ZabError):
    """The simulated water cannot listen where it is told (its port taken by another water,
    an address not of this machine); the message is one line for a user."""


class NodeFailure(ZabError):
    """A running node stopped because one of its tasks or threads failed: a bug, never bad
    input. The message says which and why; the process exits non-zero (systemd restarts it)."""
