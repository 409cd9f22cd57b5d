"""Operators steer cameras with Zenoh queries too (issue #30): a queryable on each image
control key this node steers.

A get on the control key (``camera/control``) carries a control as a put does, in its msgpack
or JSON payload or in its selector's parameters (``?request=now;budget_bytes=800;
roi=0.25,0.25,0.75,0.75``, ``roi=none`` to clear it, ``width``, ``height``); no parameters
changes nothing. The control is merged into the channel's settings and sent to the camera on
the reliable control channel (:meth:`bridge.core.images.Images.steer`), and the get is
answered at once on the control key with the settings now in force (JSON:
``{request, width, height, budget_bytes, roi}``), so an operator can also read them. A control
that does not fit is answered with a reply error saying why (and counted, as a put's is).
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import logging
import threading
from collections.abc import Callable
from typing import Any

import zenoh

from bridge.core.node import NodeCore
from bridge.errors import DecodeError
from bridge.runtime.zenoh_queries import parse_parameters
from bridge.wire.payloads import decode_payload

__all__ = ["ImageQueries", "control_from_parameters"]

log = logging.getLogger("zab.images")


def control_from_parameters(text: str) -> dict[str, Any]:
    """A selector's parameters as a control: ``roi`` as four fractions or ``none``; other
    names as they are (Zenoh's own, starting with ``_``, left out)."""
    out = {k: v for k, v in parse_parameters(text).items() if not str(k).startswith("_")}
    if "roi" in out:
        roi = str(out["roi"])
        out["roi"] = None if roi in ("", "none", "null") else [
            float(v) for v in roi.replace(" ", "").split(",")]
    return out


class ImageQueries:
    """The queryables of one node's image control keys."""

    def __init__(self, session: zenoh.Session, core: NodeCore, lock: threading.RLock,
                 clock: Callable[[], float], changed: Callable[[], None],
                 loop: asyncio.AbstractEventLoop) -> None:
        """``core``, used under ``lock`` at the time ``clock`` tells; ``changed``: the core
        has outputs to carry out (called on ``loop``)."""
        self.core = core
        self.lock = lock
        self.clock = clock
        self.changed = changed
        self.loop = loop
        keys = list(core.images.controls) if core.images is not None else []
        self.entities: list[Any] = [
            session.declare_queryable(key, functools.partial(self._from_zenoh, key=key))
            for key in keys]

    def _from_zenoh(self, query: zenoh.Query, key: str) -> None:
        """Zenoh thread: read the control, hand it to the loop."""
        try:
            if query.payload is not None:
                value: Any = decode_payload(query.payload.to_bytes(), str(query.encoding))
            else:
                value = control_from_parameters(str(query.parameters))
        except (DecodeError, ValueError) as exc:
            value = ValueError(f"image control {key!r}: {exc}")
        self.loop.call_soon_threadsafe(self._steer, query, key, value)

    def _steer(self, query: zenoh.Query, key: str, value: Any) -> None:
        images = self.core.images
        assert images is not None
        with self.lock:
            now = self.clock()
            if isinstance(value, ValueError):
                images.drop(key, str(value), now, "undecodable")
                answer: dict[str, Any] | ValueError = value
            else:
                try:
                    answer = images.steer(key, value, now)
                except ValueError as exc:
                    answer = exc
        try:
            if isinstance(answer, ValueError):
                query.reply_err(str(answer).encode())
            else:
                query.reply(key, json.dumps(answer).encode(),
                            encoding=zenoh.Encoding("application/json"))
            query.drop()
        except zenoh.ZError as exc:  # the getter gave up already
            log.debug("image control query already finished: %s", exc)
        self.changed()

    def close(self) -> None:
        for entity in self.entities:
            with contextlib.suppress(zenoh.ZError):
                entity.undeclare()
        self.entities.clear()
