"""Reliable channels, pure: sequence numbers, acknowledgements, retries, TTL, queue bounds."""

from __future__ import annotations

from bridge.core.ids import BLOCK
from bridge.core.loaded import parse_mission
from bridge.core.reliable import ReliableReceiver, ReliableSender, seq_after
from bridge.wire.channels import ChannelTable

MISSION = """\
mission: r
modem: {backend: sim, frame_bytes: 64}
mac: {type: none}
nodes:
  ops: {address: 1}
  auv: {address: 2}
channels:
  - name: command
    from: ops
    to: auv
    reliable: true
    queue: 4
    overflow: reject
    retries: 2
    retry_s: 5
    ttl_s: 100
    elements: [{in: cmd, out: ops/cmd, fields: [{field: n, type: int, min: 0, max: 255}]}]
"""


def make(**changes: object) -> tuple[ReliableSender, ChannelTable]:
    text = MISSION
    for key, value in changes.items():
        text = text.replace(f"    {key}: ", f"    {key}: {value}  # ", 1)
    table = parse_mission(text).table
    channel = table.by_name("command")
    return ReliableSender(channel, channel.destinations("ops"), 10.0), table


def deliver(sender: ReliableSender, receiver: ReliableReceiver, now: float,
            lose: set[int] = frozenset()) -> list[int]:
    """Send what is due; entries whose seq is in ``lose`` vanish."""
    items = sender.due(now)
    sender.sent(items, now)
    out = []
    bits = sender.channel.bits
    for item in items:
        if item.seq in lose:
            continue
        entry = sender.entry(item)
        header = entry >> bits
        out += receiver.on_entry(header >> 4, header & 0xF, entry & ((1 << bits) - 1))
    return out


def test_seq_after_wraps() -> None:
    assert seq_after(1, 255) == 2 and seq_after(255, 1) == -2 and seq_after(7, 7) == 0


def test_in_order_exactly_once_despite_loss_and_lost_acks() -> None:
    sender, _ = make()
    receiver = ReliableReceiver()
    for n in range(4):
        assert [r.state for r in sender.offer(n, 0.0)] == ["queued"]
    got = deliver(sender, receiver, 0.0, lose={1})
    assert got == [0]  # 2 and 3 wait for 1
    base, bitmap = receiver.ack()
    assert (base, bitmap) == (1, 0b11)  # bit i: base + 1 + i arrived
    reports = sender.on_ack("auv", base, bitmap, 1.0)
    assert [(r.id, r.state) for r in reports] == [(0, "delivered")]
    assert [p.seq for p in sender.due(1.0)] == []  # 1 is not due before retry_s
    got = deliver(sender, receiver, 5.0)  # only 1 is resent: 2 and 3 are held
    assert got == [1, 2, 3]
    # the acknowledgement is lost: everything is sent again later, and dropped as duplicates
    got = deliver(sender, receiver, 50.0)
    assert got == [] and receiver.duplicates == 1  # 1 again; 2 and 3 were held, not resent
    reports = sender.on_ack("auv", *receiver.ack(), 51.0)
    assert sorted(r.id for r in reports) == [1, 2, 3]
    assert not sender.flight and sender.next_time() is None


def test_retries_then_failed_and_the_receiver_skips_it() -> None:
    sender, _ = make()
    receiver = ReliableReceiver()
    sender.offer(10, 0.0)
    sender.offer(11, 0.0)
    for t in (0.0, 5.0, 15.0):  # 3 attempts of value 0, all lost; value 1 arrives, held
        deliver(sender, receiver, t, lose={0})
        sender.on_ack("auv", *receiver.ack(), t)
    reports = sender.expire(100.0 - 1)
    assert [(r.id, r.state) for r in reports] == [(0, "failed")]
    assert "3 attempts" in reports[0].reason
    # value 1 is resent with a lag that tells the receiver to skip value 0
    got = deliver(sender, receiver, 99.0)
    assert got == [11] and receiver.skipped == 1


def test_ttl_fails_queued_values() -> None:
    sender, _ = make()
    sender.offer(1, 0.0)
    reports = sender.expire(100.5)
    assert [(r.state, r.reason) for r in reports] == [("failed", "older than ttl_s=100")]


def test_queue_full_rejects_or_drops_oldest() -> None:
    sender, _ = make()
    for n in range(4):
        sender.offer(n, 0.0)
    reports = sender.offer(4, 0.0)
    assert [(r.id, r.state) for r in reports] == [(4, "failed")]
    assert "queue full" in reports[0].reason
    sender, _ = make(queue=20, overflow="drop_oldest")
    for n in range(20):
        sender.offer(n, 0.0)
    reports = sender.offer(99, 0.0)  # 16 in flight, 4 queued: the oldest queued one goes
    assert [(r.id, r.state) for r in reports] == [(16, "failed"), (20, "queued")]


def test_a_refusal_costs_a_save_once_a_block_and_a_restart_never_reuses_its_id() -> None:
    sender, _ = make()
    for n in range(4):
        sender.offer(n, 0.0)
        assert sender.changed  # an accepted value is saved before it is reported
    saves = []
    reported: set[int] = set()
    for n in range(3 * BLOCK):  # a flood on the full queue
        reports = sender.offer(n % 256, 1.0)
        assert [r.state for r in reports] == ["failed"]
        reported.add(reports[0].id)
        saves.append(sender.changed)
        if sender.changed:  # (the runtime saves here: a restart could resume from now)
            saved = sender.state()
    assert sum(saves) == 3  # one save a block of refusals, not one a refusal
    assert len(reported) == 3 * BLOCK
    # a crash after the last save: the restart numbers past every id reported since
    restarted, _ = make()
    restarted.restore(saved)
    assert restarted.offer(0, 2.0)[0].id > max(reported)
    # with no refusal, the ids go on one by one across a restart
    plain, _ = make()
    plain.offer(0, 0.0)
    again, _ = make()
    again.restore(plain.state())
    assert again.offer(0, 0.0)[0].id == 1


def test_a_receiver_that_restarted_afresh_is_sent_again_what_it_held() -> None:
    sender, _ = make()
    receiver = ReliableReceiver()
    for n in range(3):
        sender.offer(n, 0.0)
    first = sender.flight[0]
    sender.sent([first], 0.0)  # lost on the way
    entries = [(p.seq, sender.entry(p)) for p in sender.due(0.0)]
    sender.sent(sender.due(0.0), 0.0)
    for seq, bits in entries:
        receiver.on_entry(seq, (bits >> sender.channel.bits) & 0xF, {"n": seq})
    sender.on_ack("auv", *receiver.ack(), 1.0)
    assert sender.due(100.0) == [first]  # the others are held by the receiver: not resent
    sender.resync("auv")  # it restarted without its state: it holds nothing now
    assert sender.due(1.0) == sender.flight and len(sender.flight) == 3
    fresh = ReliableReceiver()
    for item in sender.due(1.0):
        fresh.on_entry(item.seq, (sender.entry(item) >> sender.channel.bits) & 0xF, item.id)
    reports = sender.on_ack("auv", *fresh.ack(), 2.0)
    assert [r.state for r in reports] == ["delivered"] * 3 and not sender.flight


def test_a_restarted_sender_numbering_past_the_base_is_delivered_not_skipped() -> None:
    sender, _ = make()
    receiver = ReliableReceiver()
    for n in range(2):
        sender.offer(n, 0.0)
    deliver(sender, receiver, 0.0)
    assert receiver.expected == 2  # the old run's two values arrived; its ack never did
    channel = sender.channel
    fresh = ReliableSender(channel, channel.destinations("ops"), 10.0, first_seq=100)
    for n in (7, 8, 9):  # a run starting at 100 (not 0, which would straddle base 2)
        fresh.offer(n, 1.0)
    assert deliver(fresh, receiver, 1.0) == [7, 8, 9] and receiver.duplicates == 0
    reports = fresh.on_ack("auv", *receiver.ack(), 2.0)
    assert [r.state for r in reports] == ["delivered"] * 3 and not fresh.flight


def test_each_run_of_a_core_numbers_its_streams_from_its_own_first_seq() -> None:
    import random

    from bridge.core.node import NodeCore

    loaded = parse_mission(MISSION)
    firsts = {NodeCore(loaded, "ops", rng=random.Random(run)).senders[0]._next_seq
              for run in range(8)}
    assert len(firsts) > 4  # eight runs, (almost) eight different starts
    again = NodeCore(loaded, "ops", rng=random.Random(3)).senders[0]._next_seq
    assert again == NodeCore(loaded, "ops", rng=random.Random(3)).senders[0]._next_seq


def test_a_modem_confirmation_holds_back_retransmission_until_the_ack_entry() -> None:
    from bridge.core.node import NodeCore

    text = MISSION.replace("    reliable: true\n", "    reliable: true\n    ack: true\n", 1)
    loaded = parse_mission(text)
    core = NodeCore(loaded, "ops")
    core.ingest("cmd", b'{"n": 3}', "application/json", 0.0)
    out = core.outbound.build(0.0, 0.0)
    assert out is not None and out.dest == 2 and out.ack is True  # unicast, modem ack asked
    core.outbound.sent(out, 0.0, confirmed=True)
    assert core.outbound.build(60.0, 60.0) is None  # confirmed by the modem: not sent again
    core.outbound.sent(core.outbound.build(0.0, 0.0, always=True), 0.0)  # an empty frame is fine
    sender = core.senders[0]
    assert isinstance(sender, ReliableSender) and sender.flight[0].held == {"auv"}
