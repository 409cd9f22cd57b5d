"""Latest-value store and MAC schedules with a fake clock (pure, deterministic)."""

from __future__ import annotations

from bridge.core.loaded import load_mission
from bridge.core.mac import FreeSchedule, TdmaSchedule
from bridge.core.store import OutboundStore
from bridge.mission.model import NoMac, TdmaMac
from tests.conftest import MISSIONS

MORPH = load_mission(MISSIONS / "morph.yaml")


def lsv_store() -> OutboundStore:
    return OutboundStore.for_node(MORPH.table.channels, "lsv")


def test_store_holds_only_channels_the_node_sends() -> None:
    names = {s.channel.name for s in lsv_store().states.values()}
    assert names == {"target_reference", "nav", "status"}


def test_newest_overwrites_and_non_latching_sends_once() -> None:
    store = lsv_store()
    target = MORPH.table.by_name("target_reference").index
    store.update(target, 0, 1, now=0.0)
    store.update(target, 0, 2, now=0.5)
    due = [s for s in store.due(1.0) if s.channel.index == target]
    assert [s.payload() for s in due] == [2]
    store.mark_sent(due, 1.0)
    assert not [s for s in store.due(100.0) if s.channel.index == target]


def test_interval_throttles() -> None:
    store = lsv_store()
    target = MORPH.table.by_name("target_reference")  # interval 10 s
    store.update(target.index, 0, 1, now=0.0)
    store.mark_sent(store.due(0.0), 0.0)
    store.update(target.index, 0, 2, now=1.0)
    assert target.index not in {s.channel.index for s in store.due(9.9)}
    assert target.index in {s.channel.index for s in store.due(10.0)}
    assert store.next_due() == 10.0


def test_latching_repeats_without_new_data() -> None:
    store = lsv_store()
    status = MORPH.table.by_name("status")  # latching, interval 15 s
    store.update(status.index, 0, 7, now=0.0)
    for t in (0.0, 15.0, 30.0):
        due = [s for s in store.due(t) if s.channel.index == status.index]
        assert len(due) == 1 and due[0].payload() == 7
        store.mark_sent(due, t)
    assert not [s for s in store.due(44.0) if s.channel.index == status.index]


def test_incomplete_channel_is_not_due() -> None:
    store = OutboundStore.for_node(MORPH.table.channels, "ssv")
    command = MORPH.table.by_name("mission_command")
    assert store.states[command.index].ready_at() is None


def test_tdma_slots_follow_the_order_and_wall_clock() -> None:
    mac = TdmaMac(type="tdma", slot_s=2.0, guard_s=0.5, order=["a", "b", "a", "c"])
    a = TdmaSchedule(mac, "a")
    starts = []
    t = 1000.0
    for _ in range(4):
        slot = a.next_slot(t)
        assert slot is not None
        starts.append(slot.start)
        assert slot.end == slot.start + 1.5
        t = slot.start
    # cycle of 8 s starting at multiples of 8: a owns slots 0 and 2 → 1000 is slot 500 (a)
    assert starts == [1004.0, 1008.0, 1012.0, 1016.0]
    assert TdmaSchedule(mac, "b").next_slot(1000.0).start == 1002.0  # type: ignore[union-attr]
    assert TdmaSchedule(mac, "c").next_slot(1000.0).start == 1006.0  # type: ignore[union-attr]
    assert TdmaSchedule(mac, "z").next_slot(1000.0) is None
    assert a.worst_gap_s() == 4.0 and TdmaSchedule(mac, "c").worst_gap_s() == 8.0


def test_two_nodes_never_share_a_slot() -> None:
    mac = TdmaMac(type="tdma", slot_s=1.5, guard_s=0.3, order=["ssv", "gcv", "lsv"])
    schedules = {n: TdmaSchedule(mac, n) for n in mac.order}
    seen: dict[float, str] = {}
    for name, schedule in schedules.items():
        t = 12345.6
        for _ in range(20):
            slot = schedule.next_slot(t)
            assert slot is not None
            assert seen.setdefault(round(slot.start, 6), name) == name
            t = slot.start


def test_free_schedule_min_gap() -> None:
    free = FreeSchedule(NoMac(type="none", min_gap_s=2.0))
    assert free.earliest(10.0, None) == 10.0
    assert free.earliest(10.0, 9.0) == 11.0
    assert free.earliest(12.0, 9.0) == 12.0


def test_a_value_arriving_while_its_frame_is_sent_stays_due() -> None:
    from bridge.core.loaded import load_mission
    from tests.conftest import MISSIONS

    table = load_mission(MISSIONS / "morph.yaml").table
    store = OutboundStore.for_node(table.channels, "lsv")
    index = table.by_name("target_reference").index
    store.update(index, 0, 5, 10.0)
    due = store.due(10.0)
    store.update(index, 0, 6, 10.05)  # arrives while the frame built at 10.0 is in the air
    store.mark_sent(due, 10.0)
    assert [s.channel.index for s in store.due(30.0) if s.channel.index == index] == [index]


def test_next_due_follows_every_change() -> None:
    """The store's heap of due times agrees with a scan over every channel (TTL included)."""
    import dataclasses
    import random

    rng = random.Random(7)
    nav = MORPH.table.by_name("nav")  # sent by lsv; with a ttl_s it is looked at each time
    channels = [dataclasses.replace(c, ttl_s=3.0) if c is nav else c
                for c in MORPH.table.channels]
    store = OutboundStore.for_node(channels, "lsv")
    assert any(s.channel.ttl_s for s in store.states.values())
    states = list(store.states.values())
    now = 0.0
    for _ in range(400):
        now += rng.choice((0.0, 0.3, 1.0, 4.0))
        state = rng.choice(states)
        if rng.random() < 0.6:
            for element in range(len(state.packed)):
                store.update(state.channel.index, element, rng.randrange(2), now)
        else:
            store.mark_sent(store.due(now), now)
        for at in (None, now, now + 5.0):
            times = [t for s in states if (t := s.ready_at(at)) is not None]
            assert store.next_due(at) == (min(times) if times else None)


def test_link_watch_finds_every_link_change() -> None:
    """Peers looked at through LinkWatch end in the states a look at every peer gives."""
    import random

    from bridge.core.link import LinkThresholds, LinkWatch

    rng = random.Random(3)
    thresholds = LinkThresholds(degraded_after_s=2.0, down_after_s=5.0)
    peers = [f"p{i}" for i in range(12)]
    watch = LinkWatch(thresholds, peers)
    heard: dict[str, float] = {}
    seen: dict[str, object] = {}
    now = 0.0
    for step in range(600):
        now += rng.choice((0.0, 0.1, 1.0, 1.0 / 3, 2.0, 3.0))
        if step == 300:
            now -= 4.0  # a clock stepping back: every peer is looked at again
        for peer in rng.sample(peers, rng.randrange(3)):
            heard[peer] = now
            watch.heard(peer)
        for peer in watch.due(now, heard):
            seen[peer] = thresholds.state(heard.get(peer), now)
        assert seen == {p: thresholds.state(heard.get(p), now) for p in peers}


def _look(watch: object, thresholds: object, heard: dict[str, float],
          seen: dict[str, object], now: float) -> None:
    """Re-evaluate the peers LinkWatch names, as NodeCore.update_links does."""
    for peer in watch.due(now, heard):  # type: ignore[attr-defined]
        seen[peer] = thresholds.state(heard.get(peer), now)  # type: ignore[attr-defined]


def test_link_watch_told_the_hearing_times_finds_every_link_change() -> None:
    """As NodeCore uses it (each hearing with its time, a look at once when the peer was not
    up), through clock steps back of every size: the states a look at every peer gives."""
    import random

    from bridge.core.link import LinkState, LinkThresholds, LinkWatch

    for seed in range(40):
        rng = random.Random(seed)
        degraded = rng.choice((1.0, 2.0, 3.0))
        thresholds = LinkThresholds(degraded, degraded + rng.choice((0.0, 1.0, 1.0 / 3)))
        peers = [f"p{i}" for i in range(rng.randint(1, 12))]
        watch = LinkWatch(thresholds, peers)
        heard: dict[str, float] = {}
        seen: dict[str, object] = {}
        now = 0.0
        for _ in range(400):
            now += rng.choice((0.0, 0.1, 1.0, 1.0 / 3, 0.7, 2.0, 3.0))
            if rng.random() < 0.02:
                now -= rng.choice((0.5, 4.0))  # the clock steps back
            for peer in rng.sample(peers, rng.randrange(min(4, len(peers) + 1))):
                heard[peer] = now
                watch.heard(peer, now)
                if seen.get(peer) is not LinkState.UP:
                    _look(watch, thresholds, heard, seen, now)
            _look(watch, thresholds, heard, seen, now)
            assert seen == {p: thresholds.state(heard.get(p), now) for p in peers}
