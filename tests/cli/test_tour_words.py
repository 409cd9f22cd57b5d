"""The tour's words and its synthetic vehicles, without running it: numbers to their step,
plausible data, how long to wait after a dive, and what counts as sent while surfaced."""

from __future__ import annotations

import itertools


def test_numbers_print_to_their_step_without_float_noise() -> None:
    from bridge.cli.rounding import number, significant

    assert [significant(s) for s in (1.072883e-05, 0.024639, 0.1, 1.0, 0.05, 2.5e6)] == [
        "0.0000107", "0.0246", "0.1", "1", "0.05", "2500000"]
    assert number(9.536743164062498e-08, 0.1) == "0.0"
    assert number(3.2350001, 0.0246) == "3.235"
    assert number(14, 1.0) == "14"
    assert number(0.825, 0.05) == "0.825"


def test_synthetic_status_varies_slowly_and_plausibly() -> None:
    from bridge.cli.demo import synthetic_value
    from bridge.codec import FieldSpec

    battery = FieldSpec(field="battery", type="int", min=0, max=100)
    mode = FieldSpec(field="mode", type="enum", values=["idle", "transit", "survey", "abort"])
    levels = [synthetic_value(battery, t, 1.0) for t in range(0, 600)]
    assert all(80 <= b <= 100 for b in levels)
    assert all(0 <= a - b <= 1 for a, b in itertools.pairwise(levels))  # drains
    assert levels[0] - levels[-1] <= 11  # about 1 % a minute
    assert {synthetic_value(mode, t, 2.0) for t in range(0, 600, 7)} == {"transit"}
    depth = FieldSpec(field="depth", min=0, max=100, resolution=0.1)
    values = [synthetic_value(depth, t, 0.5) for t in range(0, 120)]
    assert max(abs(a - b) for a, b in itertools.pairwise(values)) < 0.5


def test_the_wait_after_a_dive_covers_enough_turns_for_the_loss() -> None:
    from bridge.cli.demo_surfacing import turns_to_wait

    assert turns_to_wait(0.0) == 1
    assert turns_to_wait(0.1) == 3  # all three lost: 1 in 1000
    assert turns_to_wait(0.3) == 6
    assert 0.3 ** turns_to_wait(0.3) <= 1e-3 < 0.3 ** (turns_to_wait(0.3) - 1)


def test_sends_while_up_count_frames_begun_between_the_vehicles_own_switches() -> None:
    from bridge.cli.demo_surfacing import SentAtSwitches
    from bridge.core.events import FrameSent, Surfaced

    def frame(at: float, *names: str) -> FrameSent:
        return FrameSent(at, 8, list(names), None, b"")

    sent = SentAtSwitches("cv2", "ssv")
    sent("cv2", frame(0.5, "nav", "status"))
    sent("cv2", Surfaced(1.0, "ssv", True))
    # begun before the switch (its contents chosen then), reported once on the water: before
    sent("cv2", frame(0.9, "nav", "status"))
    sent("cv2", frame(1.5, "nav"))
    assert sent.while_up() is None  # not dived yet
    sent("ssv", Surfaced(2.0, "cv2", False))  # the surface's view: not these
    sent("ssv", frame(2.5, "status"))  # nor the surface's frames
    sent("cv2", frame(3.0, "nav"))
    sent("cv2", Surfaced(5.0, "ssv", False))
    sent("cv2", frame(5.0, "nav", "status"))  # after the dive
    assert sent.while_up() == {"nav": 2}


def test_a_tour_numbers_only_the_parts_its_mission_has() -> None:
    import io
    from pathlib import Path

    from rich.console import Console

    from bridge.cli.demo import VehicleApps, tour_mission, tour_parts
    from bridge.cli.tour import Tour

    loaded, _ = tour_mission(Path("deploy/missions/zspace.yaml"), 0.1)
    parts = tour_parts(loaded, VehicleApps(loaded, print))
    assert parts == ["values", "latest", "queries", "surfacing", "pictures"]  # no ranging,
    out = io.StringIO()  # no command (a camera's control is not the tour's command)
    tour = Tour(loaded, Console(file=out, width=200), 70)
    tour.plan(parts)
    assert not tour.part("command") and not tour.part("fixes")
    assert tour.part("queries") and tour.part("pictures") and tour.part("summary")
    assert [line.rstrip("─ ") for line in out.getvalue().splitlines()] == [
        "3. A Zenoh get across the water", "5. A picture across the water, refining",
        "6. Summary"]


def test_range_errors_are_told_apart_by_what_moved_during_the_exchange() -> None:
    from bridge.cli.tour import range_error_lines

    ranges = [("lsv", "cv1", 0.02), ("cv1", "lsv", 0.04), ("lsv", "ssv", 1.9),
              ("ssv", "cv2", 2.1), ("cv2", "gcv", 0.03)]
    first, why = range_error_lines(ranges, {"ssv"}, 7.5)
    assert first == ("5 acoustic ranges measured; median error against the simulated distance "
                     "when each completed 0.04 m.")
    assert "(up to 7.5 s apart)" in why and "median 0.03 m (3 ranges)" in why
    assert "To ssv, which they sail away from, it changes: median 2.10 m (2 ranges)" in why
    assert range_error_lines([("a", "b", 0.01)], set(), None) == [
        "1 acoustic range measured; median error against the simulated distance when each "
        "completed 0.01 m."]


def test_late_frames_are_counted_off_the_screen_and_other_warnings_stay() -> None:
    import logging

    from bridge.cli.demo import LateFrames

    late = LateFrames()

    def record(message: str) -> logging.LogRecord:
        return logging.LogRecord("zab", logging.WARNING, __file__, 1, message, (), None)

    assert not late.filter(record("lsv: send failed: sim modem 'lsv': water refused the "
                                  "frame: expired: asked to start 11.9 ms ago"))
    assert late.filter(record("lsv: send failed: modem unplugged"))
    # a frame due as the tour ends, its modem closed already: not shown, not counted
    assert not late.filter(record("cv2: send failed: sim modem 'cv2' is closed"))
    assert late.by_node == {"lsv": 1}


def test_a_vehicle_answers_a_get_with_its_own_data() -> None:
    from pathlib import Path

    from bridge.cli.demo import VehicleApps, tour_mission
    from bridge.cli.demo_queries import _reply_value

    loaded, _ = tour_mission(Path("deploy/missions/morph.yaml"), 0.1)
    apps = VehicleApps(loaded, print, truth=lambda node, t: {"gcv": (0, 0, 12.0),
                                                              "lsv": (0, 0, 10.0)}[node])
    apps.latest[("gcv", "battery")] = 81
    spec = loaded.table.queries[0]
    gcv = _reply_value(spec, 0.0, {}, lambda name: apps.own("gcv", name))
    lsv = _reply_value(spec, 0.0, {}, lambda name: apps.own("lsv", name), phase=2.0)
    assert gcv == {"battery": 81, "depth_m": 12.0}  # its status, its depth
    assert lsv["depth_m"] == 10.0 and lsv["battery"] != gcv["battery"]


def test_first_arrivals_are_shown_in_part_one_only() -> None:
    """An arrival after part 1 ended (its wait ran out before three channels showed
    rounding) is not printed under a later part."""
    import io
    from pathlib import Path

    from rich.console import Console

    from bridge.cli.demo import EXAMPLE_TRIES, VehicleApps, tour_mission
    from bridge.cli.tour import Tour

    loaded, _ = tour_mission(Path("deploy/missions/zspace.yaml"), 0.1)
    out = io.StringIO()
    apps = VehicleApps(loaded, print, tour=Tour(loaded, Console(file=out, width=200), 70))
    (dst, _), (src, channel, element) = next(
        (where, route) for where, route in apps.routes.items() if route[1].name == "alarm")
    apps.history[(src, channel.elements[element].input_key(src))] = [(0.0, {"leak": False})]
    apps.examples_done.set()  # part 1 is over
    for _ in range(EXAMPLE_TRIES + 1):  # (arrivals that show no rounding are passed over)
        apps._example(dst, (src, channel, element), {"leak": False})
    assert out.getvalue() == "" and apps.examples == []
    apps.examples_done.clear()  # while part 1 lasts, an arrival is shown
    for _ in range(EXAMPLE_TRIES + 1):
        apps._example(dst, (src, channel, element), {"leak": False})
    assert f"{src} → {dst}: {src}/alarm (alarm, 1 bit)" in out.getvalue()


def test_part_two_tells_of_a_channel_the_programs_publish_every_second() -> None:
    """Not the camera (umci_relay's first channel sent on news): its picture is put once."""
    from pathlib import Path

    from bridge.cli.demo import VehicleApps, latest_channel, tour_mission

    for mission, name in (("umci_relay", "grip"), ("morph", "nav"), ("zspace", "temps")):
        loaded, _ = tour_mission(Path(f"deploy/missions/{mission}.yaml"), 0.1)
        assert latest_channel(loaded, VehicleApps(loaded, print)).name == name, mission


def test_a_command_to_one_vehicle_waits_for_it_not_each_of_it() -> None:
    import io
    from pathlib import Path

    from rich.console import Console

    from bridge.cli.demo import tour_mission
    from bridge.cli.tour import Tour

    loaded, _ = tour_mission(Path("deploy/missions/umci_relay.yaml"), 0.1)
    out = io.StringIO()
    tour = Tour(loaded, Console(file=out, width=400), 70)
    tour.command_sent("surface", "rov2/goto", '{"x": 0.0}', ("rov2",), 0.1, "@zab/d")
    tour.command_sent("ssv", "command", '{"leg": 7}', ("gcv", "lsv"), 0.1, "@zab/d")
    one, two = out.getvalue().splitlines()
    assert "surface's bridge resends it until rov2 confirms (the water loses 10% of" in one
    assert "ssv's bridge resends it until each of gcv, lsv confirms" in two


def test_the_tour_announces_the_picture_s_size_as_it_crosses() -> None:
    """The picture is cut to whole fragments of the camera's frame (zspace: 93 of 112 B):
    the tour's words allow for it, and say the most it can be."""
    import re
    from pathlib import Path

    from bridge.cli.demo import tour_mission
    from bridge.report.check import check_mission

    for mission in ("morph", "zspace", "umci_relay"):
        loaded, changes = tour_mission(Path(f"deploy/missions/{mission}.yaml"), 0.1)
        said = next(c for c in changes if "camera" in c)
        most = re.search(r"a progressive picture of up to (\d+) bytes, whole fragments", said)
        assert most, said
        budget = check_mission(loaded).data["images"][0]["budget_bytes"]
        assert budget <= int(most.group(1)), (mission, budget)


def test_the_summary_says_why_frames_were_lost() -> None:
    """umci_relay's tour announced 10% loss and summed up 25%: rov2 is out of the surface's
    range, by design (it is reached through rov1); the summary tells the causes apart."""
    import io
    from pathlib import Path

    from rich.console import Console

    from bridge.cli.demo import tour_mission
    from bridge.cli.tour import Tour

    loaded, _ = tour_mission(Path("deploy/missions/umci_relay.yaml"), 0.1)
    out = io.StringIO()
    tour = Tour(loaded, Console(file=out, width=400), 70)
    links = [{"sent": 100, "lost": {"loss": 9, "out_of_range": 20}},
             {"sent": 40, "lost": {"loss": 4, "collision": 0}}]
    tour.summary({"channels": {}, "links": links}, {}, [], set(), None)
    tour.summary({"channels": {}, "links": [{"sent": 10, "lost": {}}]}, {}, [], set(), None)
    lines = [line for line in out.getvalue().splitlines() if line.startswith("The water")]
    assert lines == [
        "The water carried 140 frame copies between vehicles and lost 33 (24%: 20 out of "
        "range, 13 to the tour's random loss).",
        "The water carried 10 frame copies between vehicles and lost 0 (0%)."]


def test_each_member_of_a_key_family_gets_values_of_its_own() -> None:
    """The zspace tour's GUI showed fleet/auv1/depth_order and fleet/auv2/depth_order at the
    same 78.469, and a vehicle's three temperatures alike: one value put on every member."""
    from pathlib import Path

    import msgpack

    from bridge.cli.demo import VehicleApps, tour_mission

    loaded, _ = tour_mission(Path("deploy/missions/zspace.yaml"), 0.1)
    apps = VehicleApps(loaded, print)
    put: dict[str, dict] = {}

    class Session:
        def put(self, key: str, payload: bytes, **_: object) -> None:
            put[key] = msgpack.unpackb(payload)

    apps.sessions = {node: Session() for node in loaded.mission.nodes}  # type: ignore[misc]
    apps.publish_once(100.0)
    depths = [put[f"fleet/{vehicle}/depth_order"]["depth_m"] for vehicle in ("auv1", "auv2")]
    temps = [put[f"auv1/sensors/{name}/temp"]["celsius"] for name in "abc"]  # auv1's
    contacts = [put[f"auv1/contacts/k{i}"]["range_m"] for i in range(3)]
    assert len(set(depths)) == 2 and len(set(temps)) == 3 and len(set(contacts)) == 3, put
    assert all(-2 <= t <= 40 for t in temps) and all(0 <= d <= 100 for d in depths)


def test_a_stop_before_the_end_cuts_the_story_short_and_says_so() -> None:
    """Ctrl-C mid-tour: the story stops where it is (the stopping fleet's tokens going are
    no dive to tell) and one line says the rest is skipped; a stop at the tour's end says
    nothing."""
    import asyncio
    import io
    import time

    from rich.console import Console

    from bridge.cli.demo import cut_short
    from bridge.cli.tour import Tour
    from bridge.core.loaded import load_mission
    from tests.conftest import MISSIONS

    async def run(end_in: float) -> tuple[str, bool]:
        out = io.StringIO()
        tour = Tour(load_mission(MISSIONS / "morph.yaml"), Console(file=out, width=100), 60.0)
        stop = asyncio.Event()
        told: list[str] = []

        async def story() -> None:
            await stop.wait()
            await asyncio.sleep(0.05)  # the fleet closing: a token goes
            told.append("cv2 dived")

        task = asyncio.create_task(story())
        watcher = asyncio.create_task(cut_short(stop, task, tour, time.time() + end_in))
        await asyncio.sleep(0.01)
        stop.set()
        await asyncio.gather(task, watcher, return_exceptions=True)
        return out.getvalue(), bool(told)

    said, told = asyncio.run(run(30.0))
    assert "Stopped early: the rest of the tour is skipped." in said and not told
    said, told = asyncio.run(run(-1.0))
    assert said == "" and told


def test_gets_ended_by_a_stopping_bridge_are_no_failures() -> None:
    from bridge.cli.demo_queries import failure

    assert failure("gcv: acoustic link down") == "acoustic link down"
    assert failure("no reply") == "no reply"
    assert failure("cv1: the bridge is stopping") is None


def test_while_up_starts_when_the_surface_bridge_saw_the_vehicle() -> None:
    """The tour counts acoustic copies published at the surface while the vehicle was up from
    when the surface's own bridge saw it over IP: a frame it decoded a moment before (the
    token had reached the tour's application first) is published by design (one beside a
    full suite was counted, and the tour said '1 acoustic values … while up')."""
    import io
    from pathlib import Path

    from rich.console import Console

    from bridge.cli.demo_surfacing import SentAtSwitches
    from bridge.cli.tour import Tour
    from bridge.core.events import Surfaced
    from bridge.core.loaded import load_mission

    sent = SentAtSwitches("cv2", "ssv")
    sent("cv2", Surfaced(100.2, "ssv", True))  # the vehicle's view: not the surface's
    assert sent.surface_saw_up(90.0) is None
    sent("ssv", Surfaced(100.4, "cv2", True))
    sent("ssv", Surfaced(114.0, "cv2", False))
    assert sent.surface_saw_up(90.0) == 100.4 and sent.surface_saw_up(101.0) is None
    out = io.StringIO()
    tour = Tour(load_mission(Path("deploy/missions/morph.yaml")), Console(file=out, width=120),
                60.0)
    tour.acoustic_while_up("cv2", {}, {}, 1, 0, "ssv")
    assert "1 acoustic value of cv2 published at ssv while up" in out.getvalue()


def test_latest_value_words_hold_when_turns_come_faster_than_values() -> None:
    """bluerov_images: status every 1 s, the ROV's turn every 0.64 s; the tour said 'the about
    1 published in between are superseded', as if every turn fell a value behind."""
    import io
    from pathlib import Path

    from rich.console import Console

    from bridge.cli.demo import tour_mission
    from bridge.cli.tour import Tour

    loaded, _ = tour_mission(Path("deploy/missions/bluerov_images.yaml"), 0.1)
    status = next(c for c in loaded.table.channels if c.name == "status")
    out = io.StringIO()
    tour = Tour(loaded, Console(file=out, width=400), 70)
    tour.latest(status, 1.0, "rov", 0.64)
    said = " ".join(out.getvalue().split())
    assert "Whenever a turn finds more than one new value" in said
    assert "about 1 published in between" not in said
    out.seek(0)
    out.truncate()
    tour.latest(status, 1.0, "rov", 7.5)
    assert "about 7 published in between are superseded" in " ".join(out.getvalue().split())


def test_a_mission_of_slow_turns_is_told_the_tour_may_be_short() -> None:
    """acoustic_line's 16 s turns: a 70 s tour left parts 'not seen before the tour moved
    on' with no word why; the intro now says so and what duration shows more."""
    from pathlib import Path

    from bridge.cli.demo import tour_mission
    from bridge.cli.tour import slow_turns

    line, _ = tour_mission(Path("deploy/missions/acoustic_line.yaml"), 0.1)
    said = slow_turns(line, 70.0)
    assert said is not None and "every 16 s" in said and "--duration 120" in said
    assert slow_turns(line, 120.0) is None
    morph, _ = tour_mission(Path("deploy/missions/morph.yaml"), 0.1)
    assert slow_turns(morph, 70.0) is None
