"""The frame key: where a runtime finds it, and whether the mission's ``wire.auth`` agrees
with the keys on this machine.

Authentication must never be off by accident. Three states of a mission:

- ``on``: ``wire.auth`` is given; a key must be found (``$ZAB_KEY`` or the key file), or
  ``zab run`` and ``zab check`` refuse (exit 2). ``zab sim``, ``zab demo`` and test fleets,
  which run every node in one process, use a throwaway key instead, and say so.
- ``off``: ``wire.auth: off``, frames unauthenticated on purpose. Keys are not looked at.
- ``unsaid``: no ``wire.auth``. Refused while a key is present (``$ZAB_KEY``): the operator
  meant to authenticate and nothing would. With no key it runs, with a warning.
"""

from __future__ import annotations

import functools
import hashlib
import os
import secrets
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from bridge.errors import MissionError
from bridge.mission.model import Auth, Mission
from bridge.wire.seal import KeyRing

DEFAULT_KEY_ENV = "ZAB_KEY"
"""Where operators put the mission key (docs/deploy.md), and where a stray key is looked for."""


def find_key(key_env: str, key_file: Path | None) -> bytes | None:
    """The mission key from the environment variable, else the file (never from the mission);
    None when neither holds one. A key file that exists but cannot be read is a MissionError."""
    value = os.environ.get(key_env)
    if value:
        return value.encode()
    if key_file is not None and key_file.exists():
        try:
            key = key_file.read_bytes().strip()
        except OSError as exc:
            raise MissionError(f"cannot read the frame key file {key_file}: {exc}") from None
        if key:
            return key
    return None


def load_key(key_env: str, key_file: Path | None) -> bytes:
    """The mission key, as :func:`find_key`; MissionError when there is none."""
    key = find_key(key_env, key_file)
    if key is None:
        where = f"${key_env}" + (f" or {key_file}" if key_file else "")
        raise MissionError(f"wire.auth is on but no key was found in {where}")
    return key


@functools.cache
def throwaway_key() -> bytes:
    """A random key, the same for the whole process: what ``zab sim``, ``zab demo`` and test
    fleets (every node in one process) authenticate with when no mission key is given."""
    return secrets.token_hex(32).encode()


def key_for_run(key_env: str, key_file: Path | None) -> tuple[bytes, bool]:
    """The mission key if present, else the process's throwaway key; and whether it is the
    throwaway one (say so: it cannot talk to nodes in other processes)."""
    key = find_key(key_env, key_file)
    return (throwaway_key(), True) if key is None else (key, False)


def with_next_key(auth: Auth, key: bytes, throwaway: bool = False) -> bytes | KeyRing:
    """``key`` alone, or with the next key ``auth.next_key`` names (key rotation), found like
    the mission key; a throwaway ``key``'s next is derived from it. MissionError when the
    mission names a next key and there is none."""
    nxt = auth.next_key
    if nxt is None:
        return key
    found = find_key(nxt.key_env, nxt.key_file)
    if found is None and throwaway:
        found = hashlib.sha256(b"zab next key " + key).hexdigest().encode()
    if found is None:
        where = f"${nxt.key_env}" + (f" or {nxt.key_file}" if nxt.key_file else "")
        raise MissionError(f"wire.auth.next_key takes over at {nxt.at.isoformat()} but no key "
                           f"was found in {where}")
    return KeyRing(key, found, nxt.at.timestamp(), nxt.overlap_s)


def keys_for_run(auth: Auth) -> tuple[bytes | KeyRing, bool]:
    """:func:`key_for_run` of the mission key, with the next key if the mission names one."""
    key, throwaway = key_for_run(auth.key_env, auth.key_file)
    return with_next_key(auth, key, throwaway), throwaway


MIN_KEY_BYTES = 16  # what the Authenticator accepts
MAKE_KEY = "openssl rand -hex 32"  # one way to make a key (docs/deploy.md)

State = Literal["on", "off", "unsaid"]


@dataclass(frozen=True)
class FrameKey:
    """What the mission says about authentication and what this machine holds."""

    state: State
    source: str | None = None  # where the key was found: "$ZAB_KEY" or the key file's path
    problem: str | None = None  # why the node must not run (None: fine)
    tag_bytes: int = 0
    looked: bool = True  # False: the keys here were not looked at (zab check --no-key)
    encrypted: bool = False

    @property
    def throwaway(self) -> bool:
        """Authenticated but no key here: a simulation would use a throwaway key."""
        return self.state == "on" and self.looked and self.source is None

    def describe(self) -> str:
        """One line for ``zab check`` and the start of ``zab run``."""
        if self.state == "off":
            return "frames are not authenticated (wire.auth: off, on purpose)"
        if self.state == "unsaid":
            return ("frames are NOT authenticated: the mission does not say wire.auth (add "
                    "`auth: {}` under wire to authenticate, or `auth: off` to mean it)")
        where = (f"key from {self.source}" if self.source else
                 "no key on this machine" if self.looked else "key not looked for")
        how = "encrypted and authenticated (AES-CCM, " if self.encrypted else "authenticated ("
        return f"frames {how}{self.tag_bytes}-byte tag, {where})"

    def as_json(self) -> dict[str, Any]:
        return {"state": self.state, "source": self.source, "problem": self.problem,
                "tag_bytes": self.tag_bytes, "looked": self.looked,
                "encrypted": self.encrypted}


def frame_key(mission: Mission, *, look: bool = True) -> FrameKey:
    """Compare ``mission.wire.auth`` with the keys present (environment, key file); ``look``
    false: what the mission says alone, no key looked for (``zab check --no-key``)."""
    auth = mission.wire.auth
    if mission.wire.auth_off:
        return FrameKey("off")
    if not look:
        return FrameKey("unsaid" if auth is None else "on", looked=False,
                        tag_bytes=0 if auth is None else auth.tag_bytes)
    if auth is None:
        if os.environ.get(DEFAULT_KEY_ENV):
            return FrameKey("unsaid", f"${DEFAULT_KEY_ENV}", problem=(
                f"${DEFAULT_KEY_ENV} holds a frame key, but the mission does not authenticate "
                "frames (no wire.auth): add `auth: {}` under wire to authenticate them, or "
                "`auth: off` to send them unauthenticated on purpose"))
        return FrameKey("unsaid")
    where = f"${auth.key_env}" + (f" or {auth.key_file}" if auth.key_file else "")
    try:
        key = find_key(auth.key_env, auth.key_file)
    except MissionError as exc:
        return FrameKey("on", problem=str(exc), tag_bytes=auth.tag_bytes)
    if key is None:
        return FrameKey("on", problem=(
            f"wire.auth is on but no frame key was found in {where}: set {auth.key_env} to the "
            f"mission key (make one with `{MAKE_KEY}`), or say `auth: off` under wire to send "
            "frames unauthenticated on purpose"), tag_bytes=auth.tag_bytes)
    source = f"${auth.key_env}" if os.environ.get(auth.key_env) else str(auth.key_file)
    problem = None
    if len(key) < MIN_KEY_BYTES:
        problem = (f"the frame key in {source} is {len(key)} bytes; at least {MIN_KEY_BYTES} "
                   f"are needed (make one with `{MAKE_KEY}`)")
    else:
        try:
            with_next_key(auth, key)
        except MissionError as exc:
            problem = str(exc)
    return FrameKey("on", source, problem, auth.tag_bytes, encrypted=auth.encrypt)


def throwaway_note(mission: Mission) -> str | None:
    """What ``zab sim``/``zab demo`` print when they authenticate with a throwaway key."""
    auth = mission.wire.auth
    if auth is None or not frame_key(mission).throwaway:
        return None
    where = f"${auth.key_env}" + (f" or {auth.key_file}" if auth.key_file else "")
    return f"frames authenticated with a throwaway key for this run (no key in {where})"
