"""``zab sim --fast`` and ``zab sim --speed X``: a mission on the virtual clock.

Every node's bridge core runs in :class:`~bridge.runtime.virtual_fleet.FastFleet` over the
pure ocean: no Zenoh, no sockets. With nobody publishing, each input key is fed synthetic
values (random valid codes of its layout) as often as its channels may send, ``interval_s``
or every :data:`FEED_S` seconds, but no faster than the node's frames can leave
(:func:`least_feed_s`), and an image channel's camera a synthetic seabed every
:data:`PICTURE_S` seconds (an operator's control key is left alone). ``--fast`` runs as fast
as the CPU allows; ``--speed X`` keeps the virtual clock at ``X`` times the wall clock (a
live view can follow it).
"""

from __future__ import annotations

import asyncio
import gc
import random
import time
import weakref
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from typing import Any

from bridge.codec import Layout
from bridge.codec.fields import ArrayCodec, BoolCodec, EnumCodec, FieldCodec, FloatCodec, IntCodec
from bridge.core.events import Event, FrameReceived
from bridge.core.loaded import LoadedMission
from bridge.errors import DecodeError, EncodeError
from bridge.report.age import AgeOfInformation
from bridge.report.model import MissionReport
from bridge.report.recorder import MissionRecorder, truth_from
from bridge.runtime.virtual_fleet import FastFleet, Timed
from bridge.wire.images import ImageSpec

FEED_S = 1.0
"""How often a synthetic application publishes a key whose channels send at every turn."""
PICTURE_S = 30.0
"""How often a synthetic camera puts a new picture (a picture of a kilobyte or two takes
tens of seconds to cross an acoustic link)."""

Drawer = Callable[[random.Random], int]
"""Draws one valid code of a field."""

PACE_STEP_S = 0.1
"""Wall seconds between two checks of the pace with ``--speed``."""

DRAWS = 8
"""Random codes tried for a field of a plug-in type before falling back to its zero code."""


def synthetic_value(layout: Layout, rng: random.Random) -> Any:
    """A value the layout encodes: each field's code drawn uniformly among its valid codes
    (:func:`code_drawer`), the same distribution as drawing whole random codes until one
    decodes, without the failed draws; the all-zero codes if even that fails. Layouts with
    a header of their own (DCCL) make their own values."""
    return synthetic(layout)(rng)


def synthetic(layout: Layout) -> Callable[[random.Random], Any]:
    """:func:`synthetic_value` for one layout, its field drawers looked up once (a synthetic
    application draws a value of the same layout at every put)."""
    own = getattr(layout, "synthetic_value", None)
    if own is not None:
        return own
    drawers = [(codec.bits, draw) for codec, draw in _drawers(layout)]

    def make(rng: random.Random) -> Any:
        n = 0
        for bits, draw in drawers:
            n = (n << bits) | draw(rng)
        try:
            value = layout.unpack(n)
            layout.pack(value)
            return value
        except (DecodeError, EncodeError):
            return layout.unpack(0)

    return make


def code_drawer(codec: FieldCodec) -> Drawer:
    """Draws a valid code of one field: directly for the built-in value types whose valid
    codes are a range, else random codes until one decodes (:data:`DRAWS` tries, then 0)."""
    if isinstance(codec, FloatCodec | IntCodec):
        return _below(codec.kmax + 1)
    if isinstance(codec, EnumCodec):
        return _below(len(codec.names))
    if isinstance(codec, BoolCodec):
        return lambda rng: rng.getrandbits(1)
    if isinstance(codec, ArrayCodec):
        element, count, width = code_drawer(codec.element), codec.count, codec.element.bits

        def array(rng: random.Random) -> int:
            n = 0
            for _ in range(count):
                n = (n << width) | element(rng)
            return n

        return array

    def reject(rng: random.Random) -> int:
        for _ in range(DRAWS):
            code = rng.getrandbits(codec.bits) if codec.bits else 0
            try:
                codec.decode(code)
                return code
            except DecodeError:
                continue
        return 0

    return reject


def _below(top: int) -> Drawer:
    """``rng.randrange(top)``, the same draws, without its Python-level argument checks."""
    bits = top.bit_length()

    def draw(rng: random.Random) -> int:
        code = rng.getrandbits(bits)
        while code >= top:
            code = rng.getrandbits(bits)
        return code

    return draw


_DRAWERS: weakref.WeakKeyDictionary[Layout, list[tuple[FieldCodec, Drawer]]] = \
    weakref.WeakKeyDictionary()


def _drawers(layout: Layout) -> list[tuple[FieldCodec, Drawer]]:
    """Each field's :func:`code_drawer`, made once per layout."""
    drawers = _DRAWERS.get(layout)
    if drawers is None:
        drawers = _DRAWERS[layout] = [(f, code_drawer(f)) for f in layout.fields]
    return drawers


def least_feed_s(fleet: FastFleet, node: str) -> float:
    """The shortest period a synthetic application on ``node`` publishes at: the airtime of a
    one-byte frame on the node's quickest water (no frame of the node is shorter). A modem
    sends one frame at a time, so values fed faster would only replace each other in the
    store (or fill a reliable queue) before any frame could carry them: they would cost the
    run time, not change what crosses (``interval_s: 1e-6`` made ``zab sim --fast`` hang)."""
    return min((fleet.oceans[link].preset.airtime(1) for _, link in fleet.ports[node]),
               default=FEED_S)


def feed(fleet: FastFleet, rng: random.Random, until: float) -> int:
    """Publish synthetic values on every input key of every node until ``until``; returns the
    number of keys fed."""
    keys = 0
    for name, core in fleet.cores.items():
        images = core.images
        least = least_feed_s(fleet, name)
        for key, bindings in core.bindings.items():
            if images is not None and (key in images.inputs or key in images.controls):
                # a camera's pictures; random controls would cancel every picture
                camera = images.inputs.get(key)
                if camera is not None and camera.spec.ros2 is None:
                    publisher = _camera(fleet, name, key, camera.spec, until)
                    fleet.call_at(fleet.now + rng.uniform(0, FEED_S), publisher)
                    keys += 1
                continue
            intervals = [c.interval_s for c, _, _ in bindings if c.interval_s > 0]
            period = max(min(intervals) if len(intervals) == len(bindings) else FEED_S, least)
            publisher = _publisher(fleet, rng, name, key, bindings[0][2].layout, period, until)
            fleet.call_at(fleet.now + rng.uniform(0, period), publisher)
            keys += 1
        for key, layout in core.families.feed_keys().items():  # each member of a key family
            publisher = _publisher(fleet, rng, name, key, layout, FEED_S, until)
            fleet.call_at(fleet.now + rng.uniform(0, FEED_S), publisher)
            keys += 1
    return keys


def _camera(fleet: FastFleet, node: str, key: str, spec: ImageSpec, until: float
            ) -> Callable[[], None]:
    """A synthetic camera putting a new seabed (JPEG, or PNG if the channel takes no JPEG)
    of the channel's size on ``key`` every :data:`PICTURE_S` until ``until``."""
    from bridge.image.formats import KINDS, write_image
    from bridge.image.synthetic import seabed

    kind = "jpeg" if "jpeg" in spec.accept else "png"
    shot = 0

    def put() -> None:
        nonlocal shot
        pixels = seabed(spec.height, spec.width, shot, colour=spec.colour)
        fleet.put(node, key, write_image(pixels, kind), encoding=KINDS[kind])
        shot += 1
        if fleet.now + PICTURE_S <= until:
            fleet.call_at(fleet.now + PICTURE_S, put)

    return put


def _publisher(fleet: FastFleet, rng: random.Random, node: str, key: str, layout: Layout,
               period: float, until: float) -> Callable[[], None]:
    """A synthetic application putting a value on ``key`` every ``period`` until ``until``."""
    make = synthetic(layout)

    def publish() -> None:
        fleet.put(node, key, make(rng))
        if fleet.now + period <= until:
            fleet.call_at(fleet.now + period, publish)

    return publish


async def run_fast(
    loaded: LoadedMission,
    *,
    duration: float,
    seed: int | None = None,
    speed: float | None = None,
    record: Callable[[str, Event], None] | None = None,
    progress: Callable[[FastFleet], None] | None = None,
    stop: asyncio.Event | None = None,
    recorder: MissionRecorder | None = None,
    subscriptions: dict[str, list[str]] | None = None,
) -> MissionReport:
    """Run ``duration`` virtual seconds (``speed``: times real time; None: flat out) and
    return the report. ``record`` gets every node's events (frames included), ``progress``
    the fleet now and then; ``stop`` ends the run early; ``recorder`` gets the events and
    the ocean's positions (for the HTML report). In a ``demand`` mission the synthetic
    applications subscribe to ``subscriptions`` (node → key expressions; default: ``**`` at
    every node, so every channel is wanted)."""
    if duration <= 0:
        raise ValueError("duration must be > 0")
    if speed is not None and speed <= 0:
        raise ValueError("speed must be > 0")
    seed = seed if seed is not None else int(loaded.mission.modem.options.get("seed", 0))

    ages = AgeOfInformation()

    def on_output(timed: Timed) -> None:
        event = timed.output
        if not isinstance(event, Event):
            return
        if isinstance(event, FrameReceived):
            for channel in event.channels:
                ages.arrived(channel, timed.node, timed.time)
        if record is not None:
            record(timed.node, event)
        if recorder is not None:
            recorder(timed.node, event)

    fleet = FastFleet(loaded, seed=seed, on_output=on_output, keep_outputs=False,
                      kinds=(Event,))  # what on_output looks at
    if recorder is not None:
        ocean = fleet.ocean
        recorder.truth = truth_from({n: node.address for n, node in loaded.mission.nodes.items()},
                                    lambda address, t: ocean.position(address, t))
    if loaded.mission.demand is not None:
        for node, keys in (subscriptions if subscriptions is not None
                           else {n: ["**"] for n in loaded.mission.nodes}).items():
            for key in keys:
                fleet.subscribe(node, key)
    rng = random.Random(f"feed/{seed}")
    feed(fleet, rng, duration)
    gets = fleet.queries.synthetic(lambda layout: synthetic_value(layout, rng), duration)
    with _collector_off_the_fleet():
        started = time.perf_counter()
        step = duration if speed is None else speed * PACE_STEP_S
        while fleet.now < duration and not (stop is not None and stop.is_set()):
            fleet.run_until(min(duration, fleet.now + step))
            if progress is not None:
                progress(fleet)
            if speed is not None:  # hold the pace: virtual = speed × wall
                ahead = fleet.now / speed - (time.perf_counter() - started)
                await asyncio.sleep(max(0.0, ahead))
            else:
                await asyncio.sleep(0)
        report = MissionReport.build(loaded, fleet.cores, ages, 0.0, fleet.now,
                                     fleet.water_stats(), clock="virtual",
                                     wall_s=time.perf_counter() - started)
    if fleet.loaded.table.queries:
        report = replace(report, queries=query_summary(gets))
    if fleet.surface is not None:  # the scripted surfacings, as the vehicles saw them
        report = replace(report, surfacing={
            n: core.surfacing.switches for n, core in fleet.cores.items()
            if core.surfacing is not None and n in fleet.surface.windows})
    return report


COLLECT_EVERY = 50_000
"""Allocations between two passes of the cyclic garbage collector during a run (Python's
default is 700)."""


@contextmanager
def _collector_off_the_fleet() -> Iterator[None]:
    """Keep the cyclic garbage collector's full passes off everything alive when the run
    starts (the mission, the fleet, its cores: they live through the run) until it ends, and
    its young passes rarer. A run makes many short-lived objects, freed as they are dropped
    (they hold no cycles), so passes come often and find little: at 250 nodes × 64 channels
    full passes walked the fleet for ~10 % of the simulation's time, and with the fleet
    frozen the passes left still took ~3 %."""
    thresholds = gc.get_threshold()
    gc.freeze()
    gc.set_threshold(COLLECT_EVERY, *thresholds[1:])
    try:
        yield
    finally:
        gc.set_threshold(*thresholds)
        gc.unfreeze()


def query_summary(gets: list[Any]) -> dict[str, Any]:
    """The synthetic operators' gets: answered, failed (with why), round trips."""
    trips = [g.ended_at - g.asked_at for g in gets if g.done and g.error is None and g.replies]
    errors: dict[str, int] = {}
    for g in gets:
        if g.error is not None:
            errors[g.error] = errors.get(g.error, 0) + 1
    return {"asked": len(gets), "answered": len(trips), "open": sum(not g.done for g in gets),
            "errors": errors,
            "mean_round_trip_s": round(sum(trips) / len(trips), 3) if trips else None,
            "max_round_trip_s": round(max(trips), 3) if trips else None}
