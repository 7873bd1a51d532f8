"""The drone's pairing queryable over its per-turn handshake budget (``DroneNode._serve_pairing``):
a query over the budget is held and answered in a later turn, oldest first, not dropped (a dropped
query ends unanswered at the GS, which asks again at once: more questions to a drone already busy)."""

from collections import Counter, deque
from types import SimpleNamespace

from zdrone.core.keys import LinkKey
from zdrone.core.pairing import PairAccepted
from zdrone.nodes.drone import PAIRING_HELD, PAIRING_HOLD_S, PAIRING_PER_TURN, DroneNode


class Payload(bytes):
    def to_bytes(self) -> bytes:
        return bytes(self)


class Query:
    def __init__(self, gs: str, n: int) -> None:
        self.key_expr = f"zdrone/d1/pair/{gs}"
        self.payload = Payload(bytes([n]))
        self.n, self.replied, self.dropped = n, None, False

    def reply(self, key: str, data: bytes) -> None:
        self.replied = data

    def reply_err(self, data: bytes) -> None:
        self.replied = b"err:" + data

    def drop(self) -> None:
        self.dropped = True


def _node(queries: list[Query]) -> SimpleNamespace:
    ring = deque(queries)
    answered: list[int] = []

    def on_pair_query(gs, payload, now, secret, wall):
        answered.append(payload[0])
        return PairAccepted(b"m2-" + payload, LinkKey("d1", gs, bytes(32), bytes(32))), []

    node = SimpleNamespace(pairing=SimpleNamespace(try_recv=lambda: ring.popleft() if ring else None),
                           core=SimpleNamespace(on_pair_query=on_pair_query, counters=Counter()),
                           _do=lambda outs, now: None, _held_pairing=deque(), answered=answered)
    return node


def _queries(n: int) -> list[Query]:
    return [Query("A", i) for i in range(n)]


def test_a_query_over_the_budget_is_answered_in_a_later_turn_oldest_first():
    qs = _queries(PAIRING_PER_TURN + 3)
    node = _node(qs)
    DroneNode._serve_pairing(node, 0.0)
    assert node.answered == list(range(PAIRING_PER_TURN))
    assert [q.n for _, q in node._held_pairing] == list(range(PAIRING_PER_TURN, PAIRING_PER_TURN + 3))
    assert not any(q.dropped for q in qs[PAIRING_PER_TURN:])  # held, not dropped: the GS still waits for them
    DroneNode._serve_pairing(node, 0.05)
    DroneNode._serve_pairing(node, 0.1)
    assert node.answered == list(range(PAIRING_PER_TURN + 3))
    assert all(q.replied == b"m2-" + bytes([q.n]) and q.dropped for q in qs)
    assert node.core.counters["pair_held"] == 3 and node.core.counters["pair_deferred"] == 0


def test_the_hold_is_bounded_in_size_and_in_time():
    qs = _queries(PAIRING_PER_TURN + PAIRING_HELD + 5)
    node = _node(qs)
    DroneNode._serve_pairing(node, 0.0)
    assert len(node._held_pairing) == PAIRING_HELD and node.core.counters["pair_deferred"] == 5
    assert all(q.dropped and q.replied is None for q in qs[-5:])  # beyond the hold: dropped, the GS asks again
    DroneNode._serve_pairing(node, PAIRING_HOLD_S + 0.01)  # the GS has given up on what waited this long
    assert not node._held_pairing and node.core.counters["pair_held_expired"] == PAIRING_HELD
    assert len(node.answered) == PAIRING_PER_TURN
