"""Signed fleet revisions (``zdrone.core.revision``): fixed vectors (exact signed bytes, each refusal),
what applying one does to the effective fleet, and properties: a node's revision number only grows,
and any change to a signed revision's bytes is refused."""

from __future__ import annotations

import json
from pathlib import Path

import msgspec
import pytest
from hypothesis import given, settings, strategies as st

from zdrone.core.fleet import Fleet
from zdrone.core.keys import SigningKey
from zdrone.core.revision import (Changes, RevisionAccepted, RevisionError, RevisionRefused, apply_revision,
                                  check_revision, decode_revision, encode_revision, make_revision, with_revoked)

VECTORS = json.loads((Path(__file__).parent.parent / "vectors" / "revision.json").read_text())
BASE = msgspec.convert(VECTORS["base"], Fleet)
KEY = SigningKey(bytes.fromhex(VECTORS["fleet_seed"]))


def _current(n: int | None):
    if n is None:
        return None
    return decode_revision(VECTORS["accepted"][n - 1]["revision"].encode())


@pytest.mark.parametrize("case", VECTORS["accepted"], ids=lambda c: f"accept-{c['current']}")
def test_vector_revisions_are_accepted_with_their_exact_signed_bytes(case):
    rev = decode_revision(case["revision"].encode())
    assert rev.signed_bytes().hex() == case["signed_hex"]
    got = check_revision(case["revision"].encode(), BASE, _current(case["current"]))
    assert isinstance(got, RevisionAccepted)
    assert sorted(got.fleet.revoked) == case["revoked"]
    assert got.fleet.nodes["d1"].authorized_gs == case["authorized_d1"]
    assert got.fleet.revision == rev.number
    if "public_key_A" in case:
        assert got.fleet.nodes["A"].public_key == case["public_key_A"]
        assert got.fleet.pairing_pq is case["pairing_pq"]


def test_signing_again_gives_the_vector_bytes():
    rev = decode_revision(VECTORS["accepted"][0]["revision"].encode())
    again = make_revision(BASE, rev.number, rev.changes, KEY, note=rev.note)
    assert encode_revision(again).decode() == VECTORS["accepted"][0]["revision"]


@pytest.mark.parametrize("case", VECTORS["refused"], ids=lambda c: c["reason"])
def test_vector_revisions_are_refused_with_their_reason(case):
    got = check_revision(case["revision"].encode(), BASE, _current(case["current"]))
    assert isinstance(got, RevisionRefused) and got.reason.value == case["reason"]


def test_revoking_a_gs_takes_it_off_every_list_and_marks_it():
    fleet = apply_revision(BASE, make_revision(BASE, 1, with_revoked(Changes(), "B"), KEY))
    assert fleet.is_revoked("B") and not fleet.is_authorized("d1", "B") and fleet.is_authorized("d1", "A")
    assert BASE.is_authorized("d1", "B")  # the base fleet is never changed


@pytest.mark.parametrize("changes, what", [
    (with_revoked(Changes(), "Z"), "not a node"),
    (Changes(authorized={"A": ["B"]}), "not a drone"),
    (Changes(authorized={"d1": ["d1"]}), "not a ground station"),
])
def test_a_change_that_does_not_fit_the_fleet_is_not_signed(changes, what):
    with pytest.raises(RevisionError, match=what):
        make_revision(BASE, 1, changes, KEY)


def test_only_the_pinned_key_signs():
    with pytest.raises(RevisionError, match="not the fleet key"):
        make_revision(BASE, 1, Changes(), SigningKey(b"\x01" * 32))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(min_value=1, max_value=8), min_size=1, max_size=12))
def test_the_number_in_force_only_grows(numbers):
    current = None
    for n in numbers:
        data = encode_revision(make_revision(BASE, n, with_revoked(Changes(), "C"), KEY))
        got = check_revision(data, BASE, current)
        before = current.number if current else 0
        assert isinstance(got, RevisionAccepted) == (n > before)
        if isinstance(got, RevisionAccepted):
            current = got.revision


@settings(max_examples=80, deadline=None)
@given(st.data())
def test_any_changed_byte_is_refused(data):
    raw = bytearray(VECTORS["accepted"][1]["revision"].encode())
    i = data.draw(st.integers(min_value=0, max_value=len(raw) - 1))
    b = data.draw(st.integers(min_value=0, max_value=255).filter(lambda v: v != raw[i]))
    raw[i] = b
    got = check_revision(bytes(raw), BASE, None)
    if isinstance(got, RevisionAccepted):  # only whitespace of the indented file may change
        assert chr(raw[i]).isspace() or chr(VECTORS["accepted"][1]["revision"].encode()[i]).isspace()
        assert got.revision == decode_revision(VECTORS["accepted"][1]["revision"].encode())
