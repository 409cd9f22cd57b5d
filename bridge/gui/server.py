"""``zab gui``: one page, fed live over a websocket from the GUI's Zenoh session (aiohttp).

Routes: ``/`` the page, ``/static/...`` its script and style (all local: no internet needed),
``/ws`` the live feed, ``/state.json`` the same picture once (for scripts). The websocket
sends ``hello`` (mission description + snapshot items), then ``patch`` messages with new
items every :data:`FLUSH_S`; the page sends ``command`` messages and gets a ``reply``.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
import uuid
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import zenoh
from aiohttp import WSMsgType, web

from bridge.core.loaded import LoadedMission
from bridge.gui.commands import CommandError
from bridge.gui.feed import ZenohFeed
from bridge.gui.images import ImageControlError
from bridge.gui.model import GuiModel, shown
from bridge.mission.model import Mission
from bridge.runtime.session import origin_of, origin_tag

log = logging.getLogger("zab.gui")

STATIC_DIR = Path(__file__).resolve().parent / "static"
#: How often new items go out to the pages (and time passes for the model).
FLUSH_S = 0.1
#: Messages waiting for one page; a page this far behind is disconnected (it reconnects and
#: gets a fresh snapshot) rather than holding memory.
CLIENT_QUEUE = 256
#: Largest message a page may send (a command form).
MAX_MESSAGE_BYTES = 64 * 1024
DEFAULT_PORT = 8080


def surface_node(mission: Mission) -> str:
    """The node the GUI joins by default: the first with ``role: surface``."""
    for name, node in mission.nodes.items():
        if node.role == "surface":
            return name
    raise ValueError(f"mission {mission.mission!r} has no surface node; choose one with --node")


def dumps(message: dict[str, Any]) -> str:
    """JSON for the page; anything JSON cannot carry (NaN, bytes) is made safe first."""
    try:
        return json.dumps(message, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError):
        return json.dumps(shown(message), separators=(",", ":"), allow_nan=False)


class _Page:
    """One connected page: a bounded queue of messages and the task writing them."""

    def __init__(self, ws: web.WebSocketResponse) -> None:
        self.ws = ws
        self.queue: asyncio.Queue[str] = asyncio.Queue(CLIENT_QUEUE)
        self.writer: asyncio.Task[None] | None = None

    def send(self, text: str) -> bool:
        """Queue a message; False when the page is too far behind."""
        try:
            self.queue.put_nowait(text)
        except asyncio.QueueFull:
            return False
        return True

    async def write(self) -> None:
        while True:
            await self.ws.send_str(await self.queue.get())


def unreachable(error: str, node: str, endpoints: list[str]) -> str:
    """Why the GUI has no session to ``node``, in words an operator can act on (Zenoh's own
    message names a Rust source file)."""
    if error.startswith("Unable to connect"):
        return (f"nothing answers at {' '.join(endpoints)}: is {node}'s bridge running "
                "(zab run, zab sim or zab demo)?")
    return error.split(" at /", 1)[0]


class GuiServer:
    """The web server, the Zenoh feed and the model between them."""

    def __init__(
        self,
        loaded: LoadedMission,
        *,
        node: str | None = None,
        endpoints: Sequence[str] = (),
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.node = node or surface_node(loaded.mission)
        self.model = GuiModel(loaded, self.node)
        self.clock = clock
        self.endpoints = list(endpoints) or list(loaded.mission.nodes[self.node].zenoh.listen)
        if not self.endpoints:
            raise ValueError(f"node {self.node!r} has no zenoh.listen endpoint in the mission; "
                             "give one with --connect")
        self._bridges = {origin_tag(loaded.mission.mission, n): n  # who published a sample
                         for n in loaded.mission.nodes}
        self.feed = ZenohFeed(
            self.endpoints,
            [*self.model.keys.subscriptions(), *self.model.images.keys],
            f"{self.model.keys.prefix}/*/link/*",
            on_sample=self._sample,
            on_liveliness=self._token,
            on_connection=self._connection,
        )
        self.connection: dict[str, Any] = {"kind": "feed", "connected": False, "error": None,
                                           "endpoints": self.endpoints, "node": self.node}
        self.pages: set[_Page] = set()
        self.url: str | None = None
        self._runner: web.AppRunner | None = None
        self._stop = asyncio.Event()
        self._tasks: list[asyncio.Task[None]] = []
        self._closing: set[asyncio.Future[bool]] = set()

    # -- Zenoh side (on the event loop) --------------------------------------------------------

    def _sample(self, key: str, data: bytes, encoding: str, origin: bytes | None) -> None:
        publisher = None if origin is None else self._bridges.get(origin_of(origin))
        self.model.ingest(key, data, encoding, self.clock(), publisher)

    def _token(self, key: str, alive: bool) -> None:
        self.model.liveliness(key, alive, self.clock())

    def _connection(self, connected: bool, error: str | None) -> None:
        now = self.clock()
        first = "time" not in self.connection  # nothing said yet: say the first failure too
        was = self.connection["connected"]
        error = None if error is None else unreachable(error, self.node, self.endpoints)
        self.connection = {**self.connection, "connected": connected, "error": error,
                           "time": now}
        self.model.emit(dict(self.connection))
        if connected != was or first:
            where = f"{self.node} at {' '.join(self.endpoints)}"
            if connected:
                self.model.note("info", "gui", f"GUI connected to {where}", now)
            else:
                self.model.note("error", "gui", f"GUI not connected to {where}: {error}", now)

    # -- web side ------------------------------------------------------------------------------

    def app(self) -> web.Application:
        app = web.Application(client_max_size=MAX_MESSAGE_BYTES)
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/state.json", self._state)
        app.router.add_get("/image/{channel}/{src}", self._image)
        app.router.add_static("/static/", STATIC_DIR, follow_symlinks=False)
        return app

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC_DIR / "index.html",
                                headers={"Cache-Control": "no-cache"})

    def _hello(self) -> dict[str, Any]:
        return {"type": "hello", "time": self.clock(), "mission": self.model.description(),
                "items": [dict(self.connection), *self.model.snapshot()]}

    async def _image(self, request: web.Request) -> web.Response:
        """The latest picture of an image channel's camera (404 until one came)."""
        picture = self.model.images.picture(request.match_info["channel"],
                                            request.match_info["src"])
        if picture is None:
            raise web.HTTPNotFound(text="no picture yet")
        return web.Response(body=picture.data, content_type=picture.encoding.split(";")[0],
                            headers={"Cache-Control": "no-store"})

    async def _state(self, request: web.Request) -> web.Response:
        self._flush()
        return web.json_response(self._hello())

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        origin = request.headers.get("Origin")
        if origin is not None and urlsplit(origin).netloc != request.host:
            # a page from elsewhere must not send commands through the operator's browser
            raise web.HTTPForbidden(text="websocket from another origin")
        ws = web.WebSocketResponse(heartbeat=20.0, max_msg_size=MAX_MESSAGE_BYTES)
        await ws.prepare(request)
        page = _Page(ws)
        self._flush()  # items so far go to the other pages; this one gets them in the snapshot
        page.send(dumps(self._hello()))
        self.pages.add(page)
        page.writer = asyncio.create_task(page.write())
        try:
            async for message in ws:
                if message.type == WSMsgType.TEXT:
                    reply = self._from_page(message.data)
                    if reply is not None and not page.send(dumps(reply)):
                        break
                elif message.type == WSMsgType.ERROR:
                    break
        finally:
            self.pages.discard(page)
            page.writer.cancel()
            with contextlib.suppress(asyncio.CancelledError, ConnectionError):
                await page.writer
        return ws

    def _from_page(self, text: str) -> dict[str, Any] | None:
        """Handle one message from a page; the reply to send it, if any."""
        try:
            message = json.loads(text)
        except (ValueError, RecursionError):  # (nested past the parser's depth: not ours)
            return {"type": "reply", "ok": False, "error": "not JSON"}
        if isinstance(message, dict) and message.get("type") == "image_control":
            return self._image_control(message)
        if not isinstance(message, dict) or message.get("type") != "command":
            return {"type": "reply", "ok": False, "error": "unknown message"}
        request = message.get("request")
        now = self.clock()
        ref = uuid.uuid4().hex
        try:
            puts = self.model.command(message, ref, now)
        except CommandError as exc:
            return {"type": "reply", "request": request, "ok": False, "error": str(exc)}
        try:
            for key, payload, encoding in puts:
                self.feed.put(key, payload, ref, encoding)
        except (ConnectionError, zenoh.ZError) as exc:
            self.model.command_failed(ref, str(exc), now)
            return {"type": "reply", "request": request, "ok": False, "ref": ref,
                    "error": str(exc)}
        log.info("command %s on %s for %s: %s", ref, message.get("channel"),
                 message.get("vehicle"), puts)
        return {"type": "reply", "request": request, "ok": True, "ref": ref}

    def _image_control(self, message: dict[str, Any]) -> dict[str, Any]:
        """A page steers a camera: the control goes on the image channel's control key."""
        ref = uuid.uuid4().hex
        try:
            key, value = self.model.images.control(message)
            self.feed.put(key, value, ref)
        except (ImageControlError, ConnectionError, zenoh.ZError) as exc:
            return {"type": "reply", "request": "image_control", "ok": False, "error": str(exc)}
        log.info("image control %s on %s: %s", ref, key, value)
        return {"type": "reply", "request": "image_control", "ok": True, "ref": ref}

    def _flush(self) -> None:
        items = self.model.take()
        if not items:
            return
        text = dumps({"type": "patch", "time": self.clock(), "items": items})
        for page in list(self.pages):
            if not page.send(text):
                log.warning("a page fell %d messages behind; disconnecting it", CLIENT_QUEUE)
                self.pages.discard(page)
                closing = asyncio.ensure_future(page.ws.close())
                self._closing.add(closing)
                closing.add_done_callback(self._closing.discard)

    async def _pump(self) -> None:
        while True:
            await asyncio.sleep(FLUSH_S)
            try:
                self.model.tick(self.clock())
                self._flush()
            except Exception:  # a bug must not freeze every page: log it and go on
                log.exception("GUI update failed")

    # -- lifecycle -----------------------------------------------------------------------------

    async def start(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, *,
                    any_port: bool = False) -> str:
        """Serve on ``host:port`` (with ``any_port``, a free port if that one is taken) and
        start the feed. Returns the page's URL."""
        self._runner = web.AppRunner(self.app(), access_log=None, handle_signals=False)
        await self._runner.setup()
        try:
            site = web.TCPSite(self._runner, host, port)
            await site.start()
        except OSError:
            if not any_port:
                await self._runner.cleanup()
                self._runner = None
                raise
            site = web.TCPSite(self._runner, host, 0)
            try:
                await site.start()
            except OSError:
                await self._runner.cleanup()
                self._runner = None
                raise
        bound = self._runner.addresses[0][1]
        shown = f"[{host}]" if ":" in host else host
        self.url = f"http://{shown}:{bound}/"
        self._stop.clear()
        self._tasks = [asyncio.create_task(self.feed.run(self._stop)),
                       asyncio.create_task(self._pump())]
        return self.url

    async def stop(self) -> None:
        """Close the pages, the server and the Zenoh session; safe to call twice."""
        self._stop.set()
        for page in list(self.pages):
            await page.ws.close()
        self.pages.clear()
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None
        pump = self._tasks[1:]
        for task in pump:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks = []


async def serve_gui(
    loaded: LoadedMission,
    stop: asyncio.Event,
    *,
    node: str | None = None,
    endpoints: Sequence[str] = (),
    host: str = "127.0.0.1",
    port: int = DEFAULT_PORT,
    ready: Callable[[GuiServer], None] | None = None,
) -> None:
    """``zab gui``: serve until ``stop`` is set, then close everything."""
    server = GuiServer(loaded, node=node, endpoints=endpoints)
    await server.start(host, port)
    try:
        if ready is not None:
            ready(server)
        await stop.wait()
    finally:
        await server.stop()
