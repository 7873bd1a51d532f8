"""TESTBED: the predicates of the operator-control scenarios: MAVLink operator control through the GS's
GCS gateways (``zdrone.sil.operator``, ``zdrone.sil.consent_ops``). Pure, as ``zdrone.sil.verdicts``.
"""

from __future__ import annotations

from zdrone.core.records import OperatorConsentRefused, OperatorRequestDeclined, only
from zdrone.sil.verdicts import Outcome, _need


def check_operator_consent(o: Outcome) -> list[str]:
    """``operator-consent``: MAVLink operator control through the gateways (``zdrone.sil.operator``).
    B's request without consent moves nothing; a consent before the request could be read is refused;
    with A's consent B takes control within the 10 s window; each owner's operator allows the other's
    request, read, and it takes control; back with A, the flight goes on (its own
    hand-overs), with no emergency hand-over, no failsafe and the authority link never LOST."""
    s, op = o.summary, o.summary.get("operator", {})
    done = op.get("operator_done", {})
    why = _need(done.get("ok") is True, f"the operators' script failed: {done.get('failed') or 'it did not finish'}")
    window = op.get("no_consent", {}).get("window")
    moved = [h for h in s["handovers"] if window and window[0] <= (h["time"] or 0) <= window[1]]
    why += _need(window is not None and not moved, f"authority moved without consent: {moved}")
    why += _need(op.get("consent", {}).get("within_window") is True, f"consent: {op.get('consent')}")
    pairs = o.pairs
    why += _need(pairs[:5] == [("A", "B"), ("B", "A"), ("A", "B"), ("B", "A"), ("A", "B")],
                 f"hand-overs {pairs}: expected A->B (consent), B->A, A->B (takeover), B->A (release), then the flight's")
    why += _need(pairs[-1:] == [("B", "A")], f"the flight did not end under A: {pairs}")
    why += _need(all(h["kind"] == "handover" for h in s["handovers"]), "an emergency hand-over")
    why += _need(s["failsafe"] is None, "failsafe triggered")
    why += _need(s["authority_link"]["worst_state"] != "lost", "the authority link was LOST")
    why += _need(s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0,
                 f"not landed at home ({s['distance_from_home_m']} m)")
    return why


def check_consent_bound(o: Outcome) -> list[str]:
    """``consent-bound``: three authorized GSs (``zdrone.sil.consent_ops``). A consent goes to the requester
    the operator was shown and named (B, though X asked last); a consent given 3.5 s after B's 3 s request
    appeared, as X's request had just been shown, is refused (the race: X never gets it); a decline holds
    X off; an allow-takeover given in an earlier epoch, or with nothing pending, moves nothing; X never
    holds authority; then the flight goes on and lands
    at home, no emergency hand-over, no failsafe."""
    s, op = o.summary, o.summary.get("operator", {})
    done = op.get("operator_done", {})
    why = _need(done.get("ok") is True, f"the operators' script failed: {done.get('failed') or 'it did not finish'}")
    pairs = o.pairs
    why += _need(all("X" not in p for p in pairs), f"X held authority: {pairs}")
    why += _need(pairs[:4] == [("A", "B"), ("B", "A"), ("A", "B"), ("B", "A")],
                 f"hand-overs {pairs}: expected A->B (consent), B->A (takeover), A->B (consent), B->A (release)")
    why += _need(pairs[-1:] == [("B", "A")], f"the flight did not end under A: {pairs}")
    why += _need(all(h["kind"] == "handover" for h in s["handovers"]), "an emergency hand-over")
    refused = [e for e in only(o.gs.get("A", []), OperatorConsentRefused) if e.named == "X"]
    why += _need(bool(refused), "A's consent naming X was not refused")
    raced = [e for e in only(o.gs.get("A", []), OperatorConsentRefused) if e.requester == "X" and e.named is None]
    why += _need(bool(raced), "A's consent in the race (X's request just shown) is not on record as refused")
    why += _need(op.get("consent_race", {}).get("answer") == 2, f"the race: {op.get('consent_race')}")  # DENIED
    declined = [e for e in only(o.gs.get("B", []), OperatorRequestDeclined) if e.requester == "X"]
    why += _need(bool(declined), "B's operator's decline of X is not on record")
    why += _need(s["failsafe"] is None, "failsafe triggered")
    why += _need(s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0,
                 f"not landed at home ({s['distance_from_home_m']} m)")
    return why
