"""``zdrone bench crypto``: bytes added per frame and seal+open cost, ours vs the paper's Fernet; the
MAVLink 2 signing of the flight controller's link (bytes added, the drone's cost to sign a frame
to the autopilot and to check and unwrap one from it); the pairing handshake, classical (X25519) and
hybrid (X25519 + ML-KEM-768): its bytes and each side's time; and the authority record's cost
(append and sign, verify a chain of 100 000 entries)."""

from __future__ import annotations

import os
import time
from typing import Any

import msgspec

from pymavlink.dialects.v20 import common as mav

from zdrone.core.envelope import SecureLink, enable_bench_ciphers
from zdrone.core.keys import LinkKey, verify_signature
from zdrone.core.mavlink import FrameCodec

CIPHERS = ("zdrone", "fernet")


def sample_frames() -> dict[str, bytes]:
    """Typical frames of a flight, as a GS (sysid 4) or the vehicle (sysid 1) sends them."""
    gcs, veh = FrameCodec(4, 190), FrameCodec(1, 1)
    return {
        "HEARTBEAT": gcs.encode(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3)),
        "GLOBAL_POSITION_INT": veh.encode(
            mav.MAVLink_global_position_int_message(123456, 473977420, 85455940, 518000, 30000, 512, -33, 7, 9000)
        ),
        "COMMAND_LONG": gcs.encode(
            mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, float("nan"), 47.3977, 8.5456, 30.0)
        ),
        "MISSION_ITEM_INT": gcs.encode(
            mav.MAVLink_mission_item_int_message(1, 1, 3, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mav.MAV_CMD_NAV_WAYPOINT,
                                                 0, 1, 0.0, 2.0, 0.0, float("nan"), 473977420, 85521940, 30.0)
        ),
    }


def _pair(cipher: str) -> tuple[SecureLink, SecureLink]:
    enable_bench_ciphers()  # this bench measures the paper's Fernet next to ours
    key = LinkKey.from_secret("d1", "A", os.urandom(32))
    gs = SecureLink(key=key, role="gs", tx_keyexpr="zdrone/d1/up/A", rx_keyexpr="zdrone/d1/down/A",
                    peer_sysid=None, now=0.0, cipher=cipher)
    dr = SecureLink(key=key, role="drone", tx_keyexpr="zdrone/d1/down/A", rx_keyexpr="zdrone/d1/up/A",
                    peer_sysid=None, now=0.0, cipher=cipher)
    return gs, dr


def seal_open_us(cipher: str, frame: bytes, n: int) -> float:
    """Mean microseconds for one seal on one end and one open (with every check) on the other."""
    gs, dr = _pair(cipher)
    seal, opn = gs.seal, dr.open
    best = float("inf")
    for _ in range(3):  # best of three runs: the least disturbed by the rest of the machine
        t0 = time.perf_counter()
        for _ in range(n):
            opn(seal(frame), 1.0)
        best = min(best, (time.perf_counter() - t0) / n * 1e6)
    assert dr.opened == 3 * n, "bench frames must all open"
    return best


def handshake_us(n: int) -> dict[str, float]:
    """What a pairing query costs the drone: refusing a forged one by its tag, and a full handshake."""
    from zdrone.core.keys import Identity
    from zdrone.core.pairing import PairAccepted, PairingInitiator, PairingResponder, PairRefusal, PairRefused

    drone, gs, fake = Identity.generate(), Identity.generate(), Identity.generate()
    responder = PairingResponder(drone, "d1", {"A": gs.public}, frozenset({"A"}), rate=1e9, burst=1e9)
    forged = [PairingInitiator(fake, "A", "d1", drone.public).start() for _ in range(n)]
    genuine = [PairingInitiator(gs, "A", "d1", drone.public).start() for _ in range(max(1, n // 20))]
    responder.answer("A", genuine[0], 0.0, bytes(32))  # the tag key is computed once per peer
    secret = bytes(32)
    t0 = time.perf_counter()
    for m1 in forged:
        assert responder.answer("A", m1, 0.0, secret) == PairRefused(PairRefusal.BAD_MAC)
    tag = (time.perf_counter() - t0) / len(forged) * 1e6
    t0 = time.perf_counter()
    for m1 in genuine[1:]:
        assert isinstance(responder.answer("A", m1, 0.0, secret), PairAccepted)
    full = (time.perf_counter() - t0) / max(1, len(genuine) - 1) * 1e6
    return {"forged_refused_us": round(tag, 2), "handshake_us": round(full, 1)}


def handshake_modes(n: int) -> list[dict[str, Any]]:
    """One pairing, classical and hybrid: message sizes, the GS's time (message 1 and reading message
    2) and the drone's (every check and message 2), best of three runs of ``n``, microseconds."""
    from zdrone.core.keys import Identity
    from zdrone.core.pairing import PairAccepted, PairingInitiator, PairingResponder

    drone, gs = Identity.generate(), Identity.generate()
    rows = []
    for hybrid in (False, True):
        responder = PairingResponder(drone, "d1", {"A": gs.public}, frozenset({"A"}), rate=1e9, burst=1e9,
                                     require_hybrid=hybrid)
        secret = bytes(32)
        best_gs = best_drone = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            inis = [PairingInitiator(gs, "A", "d1", drone.public, hybrid=hybrid) for _ in range(n)]
            m1s = [i.start() for i in inis]
            t_gs = time.perf_counter() - t0
            t0 = time.perf_counter()
            answers = [responder.answer("A", m1, 0.0, secret) for m1 in m1s]
            best_drone = min(best_drone, (time.perf_counter() - t0) / n * 1e6)
            assert all(isinstance(a, PairAccepted) for a in answers), "bench pairings must all be answered"
            t0 = time.perf_counter()
            keys = [i.finish(a.reply) for i, a in zip(inis, answers)]  # type: ignore[union-attr]
            best_gs = min(best_gs, (t_gs + time.perf_counter() - t0) / n * 1e6)
            assert not any(i.state.value != "done" for i in inis) and len(keys) == n
        rows.append({"mode": "hybrid (X25519 + ML-KEM-768)" if hybrid else "classical (X25519)",
                     "message1_bytes": len(m1s[0]), "message2_bytes": len(answers[0].reply),  # type: ignore[union-attr]
                     "gs_us": round(best_gs, 1), "drone_us": round(best_drone, 1)})
    return rows


def audit_chain(n: int) -> dict[str, Any]:
    """The authority record (``zdrone.core.audit``): appending ``n`` decisions to a drone's record
    (hash, and a signed checkpoint every ``CHECKPOINT_EVERY``), encoding them as lines, a GS
    countersigning each checkpoint in its own chain (a witness entry), and verifying both records
    offline: the drone's chain, the GS's chain with its countersignatures, the drone's against them."""
    from zdrone.core.audit import (CHECKPOINT_EVERY, WITNESS_KIND, AuditChain, AuditCheckpoint, check_chain, countersign,
                              encode_line, witness_fields)
    import msgspec

    from zdrone.core.keys import SigningKey

    key, gs_key = SigningKey.generate(), SigningKey.generate()
    chain = AuditChain("d1", key)
    fields = {"from": "A", "to": "B", "epoch": 2, "kind": "handover", "time": 1.5e9, "position": [47.39, 8.54, 30.0]}
    t0 = time.perf_counter()
    lines = [encode_line(x) for i in range(n) for x in chain.append("handover_complete", {**fields, "epoch": i},
                                                                     1.5e9 + i)]
    lines.append(encode_line(chain.checkpoint(1.5e9 + n)))
    append_us = (time.perf_counter() - t0) / n * 1e6
    gs = AuditChain("A", gs_key)
    gs_lines: list[bytes] = []
    for raw in lines:
        if b'"audit":"checkpoint"' in raw:
            cp = msgspec.json.decode(raw, type=AuditCheckpoint)
            w = countersign("A", gs_key, "d1", key.public, *cp.raw(), cp.t)
            assert w is not None
            gs_lines += [encode_line(x) for x in gs.append(WITNESS_KIND, witness_fields(w), cp.t)]
    gs_lines.append(encode_line(gs.checkpoint(1.5e9 + n)))
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        seen: set[tuple[bytes, bytes, bytes]] = set()  # as ``zdrone audit verify``: the drone's record first
        drone = check_chain("d1", lines, key.public, seen=seen)
        witness = check_chain("A", gs_lines, gs_key.public, {"d1": key.public}, seen)
        report = drone.report(witness.countersigned, witnessed=True)
        best = min(best, time.perf_counter() - t0)
        assert witness.problem is None and report.ok and report.entries == n and report.unwitnessed == 0, \
            "the bench's records must verify, witnessed to the end"
    return {"entries": n, "checkpoint_every": CHECKPOINT_EVERY, "bytes_per_entry": round(sum(map(len, lines)) / n),
            "witness_entries": len(witness.countersigned), "append_us": round(append_us, 2),
            "verify_s": round(best, 3), "verify_us_per_entry": round(best / n * 1e6, 2)}


def fc_signing_us(frame: bytes, n: int) -> dict[str, float]:
    """The drone's per-frame cost on its flight-controller link, signing on: ``sign`` a frame to the
    autopilot (``FcSigning.outgoing``: timestamp, flag, checksum, SHA-256), ``verify`` one from it
    (``FcSigning.incoming``: signature and stream timestamp; then the signature removed before the
    frame goes on to the GSs). Best of three runs, microseconds."""
    import tempfile

    from zdrone.core import fcsign
    from zdrone.vehicle.fcsigning import FcKeyStore, FcSigning, FcState, StoredKey

    key = os.urandom(32)
    with tempfile.TemporaryDirectory() as d:
        store = FcKeyStore(os.path.join(d, "d1.fc-signing.json"))
        store.save(StoredKey(key, 0))
        signing = FcSigning(store, "prefer")
        signing.state = FcState.SIGNED
        best_sign = best_verify = float("inf")
        ts = fcsign.units(time.time())
        for _ in range(3):
            signed = [fcsign.sign(frame, key, 0, ts + i) for i in range(n)]
            ts += n
            t0 = time.perf_counter()
            for _ in range(n):
                signing.outgoing(frame)
            best_sign = min(best_sign, (time.perf_counter() - t0) / n * 1e6)
            incoming, strip = signing.incoming, fcsign.strip
            t0 = time.perf_counter()
            for f in signed:
                if incoming(f) is None:
                    strip(f)
            best_verify = min(best_verify, (time.perf_counter() - t0) / n * 1e6)
        assert signing.counters["verified_in"] == 3 * n, "bench frames must all verify"
    return {"sign_us": round(best_sign, 2), "verify_us": round(best_verify, 2)}


def attestation_cost(n: int) -> dict[str, Any]:
    """The drone's signed word on who commands it (``zdrone.core.attestation``), as it rides in each
    status beacon: bytes of the attestation, of the status with and without it, sealed; per minute on
    one radio link (one status a beacon per linked GS); sign and verify µs."""
    from zdrone.core import wire
    from zdrone.core.attestation import BEACON_S, Attester, attestation_message
    from zdrone.core.keys import SigningKey
    from zdrone.core.wire import AuthorityState

    key = SigningKey(bytes(range(32)))
    attester = Attester("d1", key)
    st = wire.AuthorityStatus(owner="A", epoch=3, state=AuthorityState.LINKED, pending_to=None, linked=["A", "B"],
                              fc_signed=True)
    wall = 1_795_000_000.0
    att = attester.attest(st, wall, renew=True)
    with_att = msgspec.structs.replace(st, attest=att)
    gs, _ = _pair("zdrone")
    bare, signed = len(gs.seal_control(st)), len(gs.seal_control(with_att))
    t0 = time.perf_counter()
    for i in range(n):
        attester.attest(st, wall + i, renew=True)
    sign_us = (time.perf_counter() - t0) / n * 1e6
    msg = attestation_message("d1", att)
    t0 = time.perf_counter()
    for _ in range(n):
        verify_signature(key.public, msg, att.sig)
    verify_us = (time.perf_counter() - t0) / n * 1e6
    per_min = 60.0 / BEACON_S
    return {"attestation_bytes": len(msgspec.msgpack.encode(att)), "status_sealed_bytes": bare,
            "status_with_attestation_sealed_bytes": signed, "beacon_s": BEACON_S,
            "attestation_bytes_per_min_per_link": round((signed - bare) * per_min),
            "status_bytes_per_min_per_link": round(signed * per_min),
            "sign_us": round(sign_us, 1), "verify_us": round(verify_us, 1)}


def raw_aead_us(frame: bytes, n: int) -> float:
    """Mean microseconds for a raw ChaCha20-Poly1305 encrypt and decrypt of ``frame`` (a 12-byte nonce,
    associated data as long as the envelope's): the floor any sealed link pays, in the same run."""
    from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305

    aead = ChaCha20Poly1305(os.urandom(32))
    nonce = os.urandom(12)
    ad = os.urandom(len(b"zdrone/v1") + len("zdrone/d1/up/A") + 2 + 3 + 8)
    enc, dec = aead.encrypt, aead.decrypt
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(n):
            dec(nonce, enc(nonce, frame, ad), ad)
        best = min(best, (time.perf_counter() - t0) / n * 1e6)
    return best


def run(quick: bool = False) -> dict[str, Any]:
    frames = sample_frames()
    out: dict[str, Any] = {"frames": [], "seal_open_us": {}, "frames_per_s": {}}
    for name, frame in frames.items():
        added = {}
        for cipher in CIPHERS:
            gs, _ = _pair(cipher)
            added[cipher] = len(gs.seal(frame)) - len(frame)
        out["frames"].append({"message": name, "frame_bytes": len(frame), "added_bytes": added})
    n = 500 if quick else 20000
    for cipher in CIPHERS:
        per = [seal_open_us(cipher, f, n if cipher == "zdrone" else n // 4) for f in frames.values()]
        us = sum(per) / len(per)
        out["seal_open_us"][cipher] = round(us, 3)
        out["frames_per_s"][cipher] = round(1e6 / us)
    per = [raw_aead_us(f, n) for f in frames.values()]
    raw = sum(per) / len(per)
    out["seal_open_us"]["raw ChaCha20-Poly1305"] = round(raw, 3)
    out["frames_per_s"]["raw ChaCha20-Poly1305"] = round(1e6 / raw)
    out["seal_open_vs_raw"] = round(out["seal_open_us"]["zdrone"] / raw, 2)
    out["pairing_query_us"] = handshake_us(400 if quick else 4000)
    out["handshake"] = handshake_modes(20 if quick else 300)
    out["audit"] = audit_chain(10_000 if quick else 100_000)
    out["attestation"] = attestation_cost(200 if quick else 2000)
    from zdrone.core import fcsign

    costs = [fc_signing_us(f, 300 if quick else 5000) for f in frames.values()]
    out["fc_signing"] = {
        "added_bytes": {name: len(fcsign.sign(f, bytes(32), 0, 1)) - len(f) for name, f in frames.items()},
        "sign_us": round(sum(c["sign_us"] for c in costs) / len(costs), 2),
        "verify_us": round(sum(c["verify_us"] for c in costs) / len(costs), 2),
    }
    out["targets"] = {"added_bytes_max": 24, "seal_open_us_max": 10.0, "seal_open_vs_raw_max": 2.0,
                      "audit_verify_100k_s_max": 1.0}
    return out


def render(result: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    rows = [[f["message"], f["frame_bytes"], f["added_bytes"]["zdrone"], f["added_bytes"]["fernet"]] for f in result["frames"]]
    print_table("Bytes per MAVLink frame", ["message", "frame bytes", "+ zdrone", "+ fernet (paper)"], rows,
                caption="target: ≤ 24 bytes added by zdrone; MAVLink 2 signing adds 13 with no secrecy")
    rows2 = [[c, result["seal_open_us"][c], result["frames_per_s"][c]] for c in result["seal_open_us"]]
    vs_raw = result.get("seal_open_vs_raw")
    print_table("Seal + open per frame (one core, every check)", ["cipher", "µs / frame", "frames / s"], rows2,
                caption=f"zdrone / raw ChaCha20-Poly1305 encrypt+decrypt of the same frames in this run: {vs_raw} x "
                        f"(target ≤ 2.0 x; Fernet is Rust since cryptography 51: it is no anchor); ≤ 10 µs")
    fc = result.get("fc_signing")
    if fc:
        print_table("MAVLink 2 signing of the flight controller's link (the drone, one core)",
                    ["added bytes / frame", "sign µs / frame", "verify µs / frame"],
                    [[max(fc["added_bytes"].values()), fc["sign_us"], fc["verify_us"]]],
                    caption="every frame to the autopilot signed, every frame from it checked and unwrapped "
                            "(the Zenoh side is unchanged: the GSs get the frames unsigned, sealed)")
    q = result.get("pairing_query_us")
    if q:
        print_table("A pairing query at the drone (one core)", ["query", "µs"],
                    [["forged (refused by its tag, no Diffie-Hellman)", q["forged_refused_us"]],
                     ["genuine (Noise KK handshake)", q["handshake_us"]]],
                    caption="the same tag and handshake protect key sharing between ground stations")
    hs = result.get("handshake")
    if hs:
        print_table("Pairing handshake, classical and hybrid (one core)",
                    ["mode", "message 1 bytes", "message 2 bytes", "GS µs", "drone µs"],
                    [[h["mode"], h["message1_bytes"], h["message2_bytes"], h["gs_us"], h["drone_us"]] for h in hs],
                    caption="hybrid: the session key holds if X25519 or ML-KEM-768 holds (fleet.json5 pairing_pq); "
                            "key sharing between ground stations costs the same")
    at = result.get("attestation")
    if at:
        print_table("The drone's signed word in every status beacon (one radio link)",
                    ["attestation bytes", "status sealed", "+ attestation", "attestation B / min", "status B / min",
                     "sign µs", "verify µs"],
                    [[at["attestation_bytes"], at["status_sealed_bytes"], at["status_with_attestation_sealed_bytes"],
                      at["attestation_bytes_per_min_per_link"], at["status_bytes_per_min_per_link"], at["sign_us"],
                      at["verify_us"]]],
                    caption=f"signed anew at every beacon ({at['beacon_s']:g} s) and at every change; one status per "
                            "beacon to each linked GS (bench traffic: the link's bytes per minute by kind)")
    au = result.get("audit")
    if au:
        print_table("Authority record (hash chain, Ed25519 checkpoint every "
                    f"{au['checkpoint_every']} entries; one core)",
                    ["entries", "bytes / entry", "append µs / entry", "verify s (all)", "verify µs / entry"],
                    [[au["entries"], au["bytes_per_entry"], au["append_us"], au["verify_s"], au["verify_us_per_entry"]]],
                    caption=f"verify: the drone's record and a GS's {au['witness_entries']} countersignatures of its "
                            "checkpoints (entries of the GS's chain); target: 100 000 entries verified in ≤ 1 s "
                            "(zdrone audit verify; --quick: 10 000)")
