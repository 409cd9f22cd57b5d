"""``zab listen`` and ``zab put``: poke a vehicle's Zenoh endpoint without writing code.

Both join the endpoint as a Zenoh client (no listening socket, no scouting) and close the
session on every path: normal end, Ctrl-C, a bad argument or a failed put.
"""

from __future__ import annotations

import io
import json
import math
import re
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

import msgpack
import zenoh

from bridge.cli.rounding import Steps, to_step
from bridge.errors import DecodeError, EncodeError, SessionError
from bridge.mission.endpoints import endpoint_problem
from bridge.mission.keyexpr import key_expr_problem
from bridge.mission.model import ZenohSettings
from bridge.runtime.session import close_quietly, open_session

if TYPE_CHECKING:
    from bridge.core.loaded import LoadedMission

MSGPACK = "application/msgpack"
IDLE_S = 0.01  # how long the listen loop sleeps when nothing has arrived
CLOSE_S = 5.0
"""Longest wait for the session's close: Zenoh's can block (a peer that does not answer its
close, zenoh-python notes' gotcha 12), and a command the user stopped must end."""
RING = 4096  # values held for the listen loop; past that the oldest are dropped, never blocking


class PokeError(Exception):
    """An endpoint, key or value that cannot be used; the message is ready to show.
    ``code``: the command's exit status (2: a bad argument; 1: nothing answers there)."""

    def __init__(self, message: str, code: int = 2) -> None:
        super().__init__(message)
        self.code = code


def key_problem(key: str) -> str | None:
    """What is wrong with a Zenoh key expression Zenoh refuses, in words: the mission file's
    checker's (:func:`bridge.mission.keyexpr.key_expr_problem`), else Zenoh's own reason
    without its source paths; None if Zenoh takes it."""
    try:
        zenoh.KeyExpr(key)
    except zenoh.ZError as exc:
        raw = str(exc)
    else:
        return None
    why = key_expr_problem(key)
    if why is None:  # Zenoh's reason: "Invalid Key Expr `k`: <reason> at <source>.rs:N."
        why = re.sub(r"\s+at \S+\.rs:\d+\.?$", "", raw.split("`: ", 1)[-1]).strip()
    return f"{why}; a key is chunks joined by '/', e.g. robot/nav"


@contextmanager
def client(endpoint: str) -> Iterator[zenoh.Session]:
    """A client session to ``endpoint``, closed however the block ends."""
    if (problem := endpoint_problem(endpoint)) is not None:
        raise PokeError(problem)
    try:
        session = open_session(ZenohSettings(mode="client", listen=[], connect=[endpoint]))
    except SessionError as exc:
        why = str(exc)
        if "invalid endpoint" in why:  # (a form endpoint_problem let through, Zenoh refused)
            raise PokeError(why[why.index("invalid endpoint"):]) from None
        if "no Zenoh router answers" in why:  # a vehicle's peer, not a router to configure
            why = "nothing answers there: is a vehicle's bridge running (zab demo, zab sim, " \
                "zab run)?"
        raise PokeError(f"cannot connect to {endpoint}: {why}", code=1) from None
    try:
        yield session
    finally:
        closing = threading.Thread(target=close_quietly, args=(session,), daemon=True,
                                   name="zab-close")
        closing.start()
        closing.join(CLOSE_S)


def decode(payload: bytes, encoding: str) -> Any:
    """A payload as Python data: a picture as :func:`picture` says it, msgpack or JSON by
    its encoding, else whichever parses."""
    if _is_picture(payload, encoding):
        return picture(payload)
    kind = encoding.split(";", 1)[0]
    tries: list[Callable[[bytes], Any]] = [lambda b: msgpack.unpackb(b, raw=False)]
    if kind in ("application/json", "text/json"):
        tries.insert(0, json.loads)
    else:
        tries.append(json.loads)
    for parse in tries:
        try:
            return parse(payload)
        except ValueError:
            continue
    try:
        return payload.decode("utf-8")
    except UnicodeDecodeError:
        return {"bytes": payload}


LONG = 64
"""Bytes longer than this print as their first half and their length, not whole."""


def _is_picture(payload: bytes, encoding: str) -> bool:
    """A JPEG or PNG by its encoding or, where that names no image type, its signature
    (:func:`bridge.image.formats.kind_of`, loaded when a sample comes: it brings numpy)."""
    from bridge.image.formats import ImageInputError, kind_of

    try:
        kind_of(payload, encoding)
    except ImageInputError:
        return False
    return True


def picture(payload: bytes) -> dict[str, Any]:
    """A PNG or JPEG as a viewer's caption: its format, size and length, and the metadata
    zab's receiving bridge writes in it (:func:`bridge.image.formats.read_text`), not its
    bytes."""
    from PIL import Image

    from bridge.image.formats import read_text

    try:
        with Image.open(io.BytesIO(payload)) as image:
            out: dict[str, Any] = {"picture": (image.format or "?").lower(),
                                   "size": list(image.size), "mode": image.mode,
                                   "length": len(payload)}
            text = read_text(image)
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError):
        return {"picture": "unreadable", "length": len(payload)}
    return out | dict(sorted(text.items()))


def _plain(value: Any) -> Any:
    """JSON-ready: floats rounded to 9 significant digits (no 9.536743164062498e-08), and
    large ones to milliseconds at least (a Unix time keeps its fraction of a second)."""
    if isinstance(value, float):
        if not math.isfinite(value):
            return str(value)
        digits = 9 if abs(value) < 1e6 else int(math.log10(abs(value))) + 4
        return float(f"{value:.{digits}g}")
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, bytes):
        if _is_picture(value, ""):  # (a ROS 2 CompressedImage's data)
            return _plain(picture(value))
        if len(value) > LONG:
            return f"{value[:LONG // 2].hex()}... ({len(value)} bytes)"
        return value.hex()
    return value


def value_of(key: str, payload: bytes, encoding: str) -> Any:
    """A sample's payload as Python data: a ROS 2 topic's CDR as its message (the type read
    from the rmw_zenoh key), else :func:`decode`."""
    if key[:1].isdigit():  # an rmw_zenoh key
        from bridge.ros2.messages import decode_sample  # (rosbags: loaded when one comes)

        try:
            value = decode_sample(key, payload)
        except DecodeError:
            value = None
        if value is not None:
            return value
    return decode(payload, encoding)


def format_sample(key: str, payload: bytes, encoding: str, steps: Steps | None = None) -> str:
    """One line: the key, then the decoded value (:func:`value_of`) as compact JSON; with
    the mission's ``steps``, a bridged value's fields printed to their channel's step."""
    value = value_of(key, payload, encoding)
    if steps is not None:
        value = to_step(value, steps.of(key))
    return f"{key} {json.dumps(_plain(value), separators=(', ', ': '))}"


def _line(sample: zenoh.Sample, steps: Steps | None) -> str:
    if sample.kind == zenoh.SampleKind.DELETE:
        return f"{sample.key_expr} (deleted)"
    return format_sample(str(sample.key_expr), sample.payload.to_bytes(), str(sample.encoding),
                         steps)


def listen(endpoint: str, keyexpr: str, show: Callable[[str], None], *,
           count: int | None = None, duration: float | None = None,
           ready: Callable[[], None] | None = None, steps: Steps | None = None) -> int:
    """Print each value arriving on ``keyexpr`` until ``count`` values, ``duration`` seconds
    or Ctrl-C; return how many were shown. ``ready`` is called once the subscriber is up;
    ``steps`` (the mission's) round bridged values to their channel's step."""
    if (problem := key_problem(keyexpr)) is not None:
        raise PokeError(f"invalid key expression {keyexpr!r}: {problem}")
    end = None if duration is None else time.monotonic() + duration
    shown = 0
    with client(endpoint) as session:
        # a channel, not a callback: a callback's thread keeps the process from exiting if
        # the close fails (it can time out under load), Ctrl-C or not
        subscriber = session.declare_subscriber(keyexpr, zenoh.handlers.RingChannel(RING))
        if ready is not None:
            ready()
        while (count is None or shown < count) and (end is None or time.monotonic() < end):
            sample = subscriber.try_recv()
            if sample is None:
                time.sleep(IDLE_S)
                continue
            show(_line(sample, steps))
            shown += 1
    return shown


def put(endpoint: str, key: str, value_json: str, ref: str,
        mission: LoadedMission | None = None) -> tuple[bytes, str]:
    """Publish the JSON value ``value_json`` on ``key`` (msgpack, or a ROS 2 topic's CDR:
    :func:`payload_for`), an operator's command (attachment ``ref:<ref>``, as the GUI's: a
    reliable channel's delivery reports echo it, and ``zab demo``'s programs leave the key to
    the operator for a while); return the payload sent and its encoding. With the
    ``mission``, a value the channels reading ``key`` cannot take is refused
    (:func:`bridge.cli.put_check.problem_with`)."""
    try:
        value = json.loads(value_json)
    except ValueError as exc:
        raise PokeError(f"the value is not JSON ({exc}): {value_json!r}") from None
    except RecursionError:
        raise PokeError("the value is nested too deeply to read") from None
    if (problem := key_problem(key)) is not None:
        raise PokeError(f"invalid key {key!r}: {problem}")
    payload, encoding = payload_for(key, value)
    if mission is not None:
        from bridge.cli.put_check import problem_with

        if (problem := problem_with(mission, key, value)) is not None:
            raise PokeError(f"cannot put on {key}: {problem}")
    with client(endpoint) as session:
        session.put(key, payload, encoding=zenoh.Encoding(encoding) if encoding else None,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                    attachment=f"ref:{ref}".encode())
    return payload, encoding


def payload_for(key: str, value: Any) -> tuple[bytes, str]:
    """What :func:`put` sends for ``value`` on ``key``: on an rmw_zenoh key the CDR message
    of the type the key names (fields left out are zero, as a ROS 2 message's defaults; a
    name the type has not is refused, not dropped), else msgpack; and its encoding (none for
    CDR, as rmw_zenoh's). :class:`PokeError`, one line, for a value that neither can hold."""
    if key[:1].isdigit():
        from bridge.ros2.messages import encode_sample  # (rosbags: loaded when needed)

        try:
            cdr = encode_sample(key, value, strict=True)
        except EncodeError as exc:
            raise PokeError(f"cannot put on {key}: {exc}") from None
        if cdr is not None:
            return cdr, ""
    try:
        return bytes(msgpack.packb(value)), MSGPACK
    except (ValueError, TypeError, OverflowError) as exc:  # (UnicodeEncodeError: a ValueError)
        raise PokeError(f"cannot put on {key}: {unpackable(value) or exc}") from None


MSGPACK_INTS = (-(2**63), 2**64 - 1)
"""The integers msgpack holds."""


def unpackable(value: Any) -> str | None:
    """Why msgpack cannot hold ``value`` (JSON data), naming where in it; None if it can."""
    todo: list[tuple[str, Any]] = [("", value)]  # (a loop: JSON nests deeper than the stack)
    while todo:
        path, item = todo.pop()
        where = f"{path}: " if path else ""
        if isinstance(item, int) and not isinstance(item, bool) \
                and not MSGPACK_INTS[0] <= item <= MSGPACK_INTS[1]:
            return f"{where}{item} is beyond msgpack's integers (-2**63 to 2**64 - 1)"
        if isinstance(item, str) and not _utf8(item):
            return f"{where}{item!r} is not UTF-8 text (a lone surrogate, \\ud800-\\udfff)"
        if isinstance(item, dict):
            for name, inner in reversed(item.items()):
                if not _utf8(str(name)):
                    return f"{where}the name {name!r} is not UTF-8 text (a lone surrogate, " \
                        "\\ud800-\\udfff)"
                todo.append((f"{path}.{name}" if path else str(name), inner))
        elif isinstance(item, list):
            todo += [(f"{path}.{i}" if path else str(i), inner)
                     for i, inner in reversed(list(enumerate(item)))]
    return None


def _utf8(text: str) -> bool:
    try:
        text.encode()
    except UnicodeEncodeError:
        return False
    return True
