"""The hand-off from Zenoh's threads to a node's loop: bounded, fair between senders, counted."""

from __future__ import annotations

import threading

from zdrone.net.inbox import MAX_BATCH, MAX_PER_SENDER, Inbox


class _Payload:
    def __init__(self, n: int) -> None:
        self.n = n

    def __len__(self) -> int:
        return self.n

    def to_bytes(self) -> bytes:
        raise AssertionError("an oversized payload must not be copied")


def test_a_flood_from_one_sender_does_not_crowd_out_another():
    """Review N1: junk on up/B used to fill the one shared queue and delay A's frames."""
    ib = Inbox(size=100)
    for i in range(10_000):
        ib.put("up", "B", b"junk")
    for i in range(5):
        ib.put("up", "A", bytes([i]))
    got: list[tuple[str, bytes]] = []
    ib.drain(0.0, lambda kind, peer, data, now: got.append((peer, data)))
    assert [d for p, d in got if p == "A"] == [bytes([i]) for i in range(5)]  # all of A's, in the first batch
    assert ib.stats() == {"up:inbox_full": 10_000 - 100}
    assert len(got) == 5 + MAX_PER_SENDER <= MAX_BATCH  # the rest of B's in the next drains
    while ib.drain(0.0, lambda kind, peer, data, now: got.append((peer, data))):
        pass
    assert len(got) == 105


def test_a_frame_arriving_during_a_flood_waits_for_few_items():
    """While the loop works through a flooded queue, a frame from another sender that arrives
    meanwhile is handled after at most ``MAX_PER_SENDER`` more items of the flood, not a whole batch."""
    ib = Inbox(size=1024)
    for _ in range(1024):
        ib.put("up", "B", b"junk")
    order: list[str] = []

    def handle(kind: str, peer: str, data: bytes, now: float) -> None:
        order.append(peer)
        if len(order) == 1:
            ib.put("up", "A", b"heartbeat")  # arrives while the first drain runs

    while len(order) < 1025:
        assert ib.drain(0.0, handle) <= MAX_PER_SENDER + 1
    assert order.index("A") <= 2 * MAX_PER_SENDER


def test_oversized_payloads_are_refused_by_length_and_counted():
    ib = Inbox()
    ib.put_payload("up", "A", _Payload(5000), limit=1024)
    assert ib.stats() == {"up:oversize": 1}
    assert ib.drain(0.0, lambda *a: None) == 0


def test_drain_waits_for_the_first_item_from_another_thread():
    ib = Inbox()
    threading.Timer(0.05, lambda: ib.put("down", "d1", b"x")).start()
    got: list[bytes] = []
    assert ib.drain(2.0, lambda kind, peer, data, now: got.append(data)) == 1 and got == [b"x"]


def test_a_drained_sender_frees_its_queue_so_many_senders_in_turn_are_served():
    """The sender bound counts senders with a backlog, not every sender ever heard (a GS serving
    100 drones hears 300 (kind, sender) pairs)."""
    from zdrone.net.inbox import MAX_SENDERS

    box, got = Inbox(), []
    for i in range(3 * MAX_SENDERS):
        box.put("down", f"d{i}", b"x")
        box.drain(0.0, lambda kind, peer, data, now: got.append(peer))
    assert len(got) == 3 * MAX_SENDERS and box.stats() == {}
    for i in range(MAX_SENDERS + 1):  # all waiting at once: the bound holds
        box.put("down", f"d{i}", b"x")
    assert box.stats() == {"down:too_many_senders": 1}


def test_the_sender_bound_grows_with_the_fleet_so_300_drones_with_a_backlog_are_all_queued():
    """Issue 30: a fixed bound of 256 refused the frames of a GS's 257th drone with a backlog (300
    drones: 18 000 frames lost in a flight). A node's bound is every peer of its fleet with every kind."""
    from zdrone.net.inbox import KINDS_PER_PEER, MAX_SENDERS, senders_bound

    bound = senders_bound(303)  # 300 drones + 3 GSs
    assert bound == KINDS_PER_PEER * 303 and senders_bound(3) == MAX_SENDERS
    box = Inbox(max_senders=bound)
    for kind in ("down", "pair", "linkkey"):
        for i in range(300):
            box.put(kind, f"d{i}", b"x")
    assert box.stats() == {}


def test_the_bytes_waiting_in_all_queues_are_bounded():
    box = Inbox(max_bytes=3000)
    for i in range(4):
        box.put("down", f"d{i}", b"x" * 1000)
    assert box.stats() == {"down:inbox_bytes": 1}
    got: list[bytes] = []
    box.drain(0.0, lambda kind, peer, data, now: got.append(data))  # drained: room again
    box.put("down", "d9", b"x" * 1000)
    assert len(got) == 3 and box.stats() == {"down:inbox_bytes": 1}
