"""The GUI server over HTTP and its websocket (no browser), and the GUI inside ``zab demo``."""

from __future__ import annotations

import asyncio
import json
import re
import threading

import aiohttp
import pytest

from bridge.errors import MissionError
from bridge.gui.server import GuiServer, dumps
from tests.conftest import MISSIONS, mission_on_free_ports, on_free_ports
from tests.gui.fleet import MISSION
from tests.harness import running_fleet


async def _hello(ws: aiohttp.ClientWebSocketResponse) -> dict:
    message = await ws.receive_json(timeout=10)
    assert message["type"] == "hello"
    return message


async def _until_connected(ws: aiohttp.ClientWebSocketResponse, hello: dict) -> None:
    """Read until the GUI's Zenoh session has joined the node."""
    items = hello["items"]
    while not any(i["kind"] == "feed" and i["connected"] for i in items):
        items = (await ws.receive_json(timeout=10)).get("items", [])


def test_what_json_cannot_carry_is_made_safe_for_the_page():
    assert json.loads(dumps({"a": float("nan"), "b": b"\x01", "c": [1.5]})) == {
        "a": None, "b": "01", "c": [1.5]}


def test_the_page_and_its_assets_are_served_locally():
    loaded = mission_on_free_ports(MISSIONS / "morph.yaml")  # nobody listens there

    async def main() -> None:
        server = GuiServer(loaded)
        url = await server.start("127.0.0.1", 0)
        try:
            async with aiohttp.ClientSession() as http:
                async with http.get(url) as response:
                    page = await response.text()
                assert response.status == 200 and "/static/app.js" in page
                # every asset the page uses is ours: nothing from the internet
                assert not re.search(r"(src|href)=\"https?://", page)
                for asset in ("app.js", "style.css"):
                    async with http.get(url + "static/" + asset) as response:
                        assert response.status == 200
                async with http.get(url + "static/../server.py") as response:
                    assert response.status in (403, 404)
        finally:
            await server.stop()

    asyncio.run(main())


def test_with_no_fleet_the_page_and_its_log_say_why():
    """`zab gui` started before the fleet: the badge and the event log name the endpoint and
    what to start, not Zenoh's source file."""
    loaded = mission_on_free_ports(MISSIONS / "morph.yaml")  # nobody listens there
    endpoint = loaded.mission.nodes["ssv"].zenoh.listen[0]
    why = f"nothing answers at {endpoint}: is ssv's bridge running (zab run, zab sim or zab demo)?"

    async def main() -> tuple[dict, dict]:
        server = GuiServer(loaded)
        url = await server.start("127.0.0.1", 0)
        try:
            async with aiohttp.ClientSession() as http, http.ws_connect(url + "ws") as ws:
                items = (await _hello(ws))["items"]
                while not any(i["kind"] == "event" for i in items):
                    items += (await ws.receive_json(timeout=10)).get("items", [])
                feed = [i for i in items if i["kind"] == "feed"][-1]
                event = [i for i in items if i["kind"] == "event"][-1]
                return feed, event
        finally:
            await server.stop()

    feed, event = asyncio.run(main())
    assert feed["connected"] is False and feed["error"] == why
    assert event["level"] == "error" and event["text"] == \
        f"GUI not connected to ssv at {endpoint}: {why}"


def test_the_websocket_says_hello_refuses_bad_messages_and_other_origins():
    loaded = mission_on_free_ports(MISSIONS / "morph.yaml")  # ssv is not running

    async def main() -> None:
        server = GuiServer(loaded)
        url = await server.start("127.0.0.1", 0)
        ws_url = url + "ws"
        try:
            async with aiohttp.ClientSession() as http:
                with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
                    await http.ws_connect(ws_url, origin="http://evil.example")
                assert refused.value.status == 403
                async with http.ws_connect(ws_url, origin=url.rstrip("/")) as ws:
                    hello = await _hello(ws)
                    mission = hello["mission"]
                    assert (mission["mission"], mission["node"]) == ("morph", "ssv")
                    assert [c["channel"] for c in mission["commands"]] == [
                        "mission_command", "surface_fix"]  # the command channel first
                    feed = next(i for i in hello["items"] if i["kind"] == "feed")
                    assert feed["connected"] is False
                    await ws.send_str("{not json")
                    assert (await ws.receive_json(timeout=5))["error"] == "not JSON"
                    await ws.send_str("[" * 30000 + "]" * 30000)  # (closed the page's socket)
                    assert (await ws.receive_json(timeout=5))["error"] == "not JSON"
                    await ws.send_json({"type": "command", "request": 1, "channel": "nav",
                                        "vehicle": "gcv", "values": {}})
                    reply = await ws.receive_json(timeout=5)
                    assert (reply["request"], reply["ok"]) == (1, False)
                    assert "sends no channel 'nav'" in reply["error"]
                    # a good command with no session to put it on fails, and says so
                    await ws.send_json({"type": "command", "request": 2,
                                        "channel": "mission_command", "vehicle": "gcv",
                                        "values": {"action": "hold", "leg": 3}})
                    reply = await ws.receive_json(timeout=5)
                    assert (reply["request"], reply["ok"]) == (2, False)
                    assert "not connected" in reply["error"]
                    states = []
                    while not states:
                        message = await ws.receive_json(timeout=5)
                        states = [i["state"] for i in message.get("items", ())
                                  if i["kind"] == "command"]
                    assert states[-1] == "failed"
        finally:
            await server.stop()

    asyncio.run(main())


def test_a_taken_port_is_an_error_unless_any_port_will_do():
    loaded = mission_on_free_ports(MISSIONS / "morph.yaml")

    async def main() -> None:
        first, second = GuiServer(loaded), GuiServer(loaded)
        url = await first.start("127.0.0.1", 0)
        port = int(url.rsplit(":", 1)[1].strip("/"))
        try:
            with pytest.raises(OSError):
                await second.start("127.0.0.1", port)
            other = await second.start("127.0.0.1", port, any_port=True)
            assert other != url
        finally:
            await second.stop()
            await first.stop()

    asyncio.run(main())


def test_a_reliable_command_shows_pending_then_delivered_per_receiver():
    """With a reliable channel, the sender's delivery reports (matched by the put's ref)
    settle the command: delivered to the chosen vehicle, and to the other receiver too."""
    text = MISSION.replace('    to: "auv[12]"\n    elements:\n      - in: command',
                           '    to: "auv[12]"\n    reliable: true\n    elements:\n'
                           '      - in: command')
    assert "reliable: true" in text
    try:
        loaded = on_free_ports(text, "reliable.yaml")
    except MissionError as exc:
        if "unknown key" not in str(exc):
            raise
        pytest.skip("this mission model has no reliable channels yet")

    async def main(url: str) -> list[dict]:
        seen: list[dict] = []
        async with aiohttp.ClientSession() as http, http.ws_connect(url + "ws") as ws:
            hello = await _hello(ws)
            assert [(c["channel"], c["reliable"]) for c in hello["mission"]["commands"]] == [
                ("command", True)]
            await _until_connected(ws, hello)
            await ws.send_json({"type": "command", "request": 1, "channel": "command",
                                "vehicle": "auv1", "values": {"action": "hold", "leg": 2}})
            deadline = asyncio.get_running_loop().time() + 30  # a few TDMA cycles, at most
            while asyncio.get_running_loop().time() < deadline:
                message = await ws.receive_json(timeout=20)
                seen += [i for i in message.get("items", ()) if i["kind"] == "command"]
                if seen and seen[-1]["state"] in ("delivered", "failed") \
                        and seen[-1]["others"].get("auv2") in ("delivered", "failed"):
                    break
        return seen

    async def with_server() -> list[dict]:
        server = GuiServer(loaded)
        try:
            return await main(await server.start("127.0.0.1", 0))
        finally:
            await server.stop()

    with running_fleet(loaded):
        seen = asyncio.run(with_server())
    assert seen and seen[0]["state"] == "pending"
    assert (seen[-1]["state"], seen[-1]["others"]) == ("delivered", {"auv2": "delivered"})
    assert "queued" in {c["detail"] for c in seen}  # the sender's reports, as they came


def test_the_page_says_when_the_node_goes_away_and_comes_back():
    """The surface bridge stops: the page hears that the GUI lost it; the bridge restarts on
    the same endpoint: the GUI's session reconnects by itself and the news flows again."""
    loaded = on_free_ports(MISSION, "restart.yaml")
    up, lost = threading.Event(), threading.Event()
    result: list[str] = []

    async def until(ws: aiohttp.ClientWebSocketResponse, wanted) -> dict:
        while True:
            for item in (await ws.receive_json(timeout=20)).get("items", ()):
                if wanted(item):
                    return item

    async def page() -> None:
        server = GuiServer(loaded)
        url = await server.start("127.0.0.1", 0)
        try:
            async with aiohttp.ClientSession() as http, http.ws_connect(url + "ws") as ws:
                await _until_connected(ws, await _hello(ws))
                await until(ws, lambda i: i["kind"] == "stats" and i["node"] == "ssv")
                up.set()
                gone = await until(ws, lambda i: i["kind"] == "feed" and not i["connected"])
                lost.set()
                await until(ws, lambda i: i["kind"] == "feed" and i["connected"])
                await until(ws, lambda i: i["kind"] == "stats" and i["node"] == "ssv")
                result.append(gone["error"])
        finally:
            await server.stop()

    thread = threading.Thread(target=asyncio.run, args=(page(),), daemon=True)
    with running_fleet(loaded, only=["ssv"]):
        thread.start()
        assert up.wait(30)
    assert lost.wait(30)
    with running_fleet(loaded, only=["ssv"]):
        thread.join(30)
    assert not thread.is_alive() and result == ["no route to the node"]
