"""Envelope bundles (``zdrone.core.bundle``): round trips, every malformed shape refused, the writer's limit."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from zdrone.core.bundle import MAX_BUNDLE, BundleWriter, pack, unpack

items = st.lists(st.binary(min_size=1, max_size=300), min_size=1, max_size=20)


@given(items)
def test_round_trip(xs: list[bytes]) -> None:
    assert unpack(pack(xs)) == xs


@given(st.binary(max_size=600))
def test_any_bytes_unpack_to_none_or_exactly_themselves(data: bytes) -> None:
    got = unpack(data)
    assert got is None or pack(got) == data


@pytest.mark.parametrize("data", [b"", b"\x00", b"\x00\x00", b"\x00\x00x", b"\x00\x05abc", b"\x00\x01a\x00",
                                  b"\x00\x01a\x00\x00"])
def test_malformed_is_none(data: bytes) -> None:
    assert unpack(data) is None


def test_pack_refuses_programming_errors() -> None:
    with pytest.raises(ValueError):
        pack([])
    with pytest.raises(ValueError):
        pack([b""])


def test_writer_keeps_order_per_destination_and_closes_full_bundles() -> None:
    w = BundleWriter(limit=100)
    for i in range(5):
        w.add("A", bytes([i]) * 40)  # 42 bytes each: two per bundle
    w.add("B", b"b")
    out = w.take()
    assert [d for d, _ in out] == ["A", "A", "A", "B"]
    a = [x for d, b in out if d == "A" for x in unpack(b) or []]
    assert a == [bytes([i]) * 40 for i in range(5)]
    assert all(len(b) <= 100 for _, b in out)
    assert not w.pending() and w.take() == []


@given(st.lists(st.tuples(st.sampled_from("ABC"), st.binary(min_size=1, max_size=500)), max_size=60))
def test_writer_delivers_everything_once_within_the_limit(adds: list[tuple[str, bytes]]) -> None:
    w = BundleWriter()
    for dest, item in adds:
        w.add(dest, item)
    out = w.take()
    assert all(len(b) <= MAX_BUNDLE for _, b in out)
    for dest in "ABC":
        assert [x for d, b in out if d == dest for x in unpack(b) or []] == [i for d, i in adds if d == dest]


def test_writer_refuses_an_item_larger_than_a_bundle() -> None:
    with pytest.raises(ValueError):
        BundleWriter(limit=64).add("A", b"x" * 63)
