"""TESTBED: the scenarios of ``zdrone demo`` and the benches, one row of ``SCENARIO_TABLE`` each.

A row names its attackers (each a separate process, ``python -m zdrone.sil.rogue --mode ...``, with
real router credentials from the run's fleet directory), the moment each is started and told to
attack, an optional fault (a GS stopped or killed, a router restarted, a link cut), and its success
predicate (``zdrone.sil.verdicts``, and the modules by kind of scenario it names). A scenario succeeds
(``zdrone demo`` exits 0) only if the flight turned out as the row expects *and* the counters show every
attack was seen and refused; the attackers write what they did to ``rogue.jsonl`` so both sides are
checked. Pure: a table of data; the launcher (``zdrone.sil.launcher``) runs it.
"""

from __future__ import annotations

import signal
import textwrap
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Callable

from zdrone.sil.attack_verdicts import (check_big_flood, check_fake_autopilot, check_fc_rogue_radio,
                                        check_gateway_flood, check_insider_heir, check_key_escrow, check_key_injection,
                                        check_linkkey_knockout, check_local_app, check_no_cert, check_no_key,
                                        check_pair_flood, check_pair_replay, check_stale_pairing, check_unauthorized,
                                        check_uplink_policy, check_view_truth)
from zdrone.sil.fault_verdicts import (LEASE_STAMPER_PERIOD_S, REVOKED_ALONE_LEASE_S, check_backhaul_cut_early,
                                       check_companion_restart, check_failsafe_recover, check_gs_crash, check_gs_hang,
                                       check_lease_stamper, check_link_loss,
                                       check_lossy_radio, check_revoke_in_flight, check_revoke_uncovered,
                                       check_revoked_alone, check_rotate_in_flight, check_router_restart,
                                       check_site_router_down, check_site_router_down_alone)
from zdrone.sil.moments import (GSS_STARTED, AIRBORNE, AT_DELIVERY, BEFORE_DRONE, BEFORE_GS_A, DRONE_RESTARTED, FAILSAFE_FIRED,
                                HANDOVERS_DONE, MISSION_STARTED, MOMENTS, REGION_ENTERED, RETURNING, TRIGGERS)
from zdrone.sil.operator_verdicts import check_consent_bound, check_operator_consent
from zdrone.sil.verdicts import fault_over_check, flight_unaffected

if TYPE_CHECKING:
    from zdrone.sil.verdicts import Outcome


@dataclass(frozen=True)
class RogueSpec:
    """One attacker process: its mode, when it starts, when it is told to attack (SIGUSR2; ``None``:
    at once), for how long (``max(min_wall, sim_s / speedup)`` wall seconds), at what rate and beside
    which GS (its router: with a router per site, that GS's site's; with ``--netns``, in its namespace)."""

    mode: str
    launch: str
    go: str | None = None
    sim_s: float = 40.0
    min_wall: float = 10.0
    rate: float | None = None
    args: tuple[str, ...] = ()  # further options of the attacker
    beside: str = "A"  # the GS whose site it connects at (site 1 unless a scenario says otherwise)

    def duration(self, speedup: float) -> float:
        return max(self.min_wall, self.sim_s / speedup)


@dataclass(frozen=True)
class Fault:
    """A GS process stopped (SIGSTOP), resumed (SIGCONT) or killed (SIGKILL) at a moment of the flight."""

    trigger: str
    target: str  # child name: gsA, gsB, router
    sig: int  # or RESTART: killed, then started again after ``down`` seconds
    text: str
    down: float = 0.0
    after: float = 0.0  # wall seconds after the trigger

@dataclass(frozen=True)
class Scenario:
    name: str
    description: str  # one line: what happens (README, --help)
    expected: str  # one line: what counts as success
    check: "Callable[[Outcome], list[str]]"  # the unmet conditions; [] = success
    rogues: tuple[RogueSpec, ...] = ()
    faults: tuple[Fault, ...] = ()
    gs_a_extra: tuple[str, ...] = ()  # further options of GS A
    sites: bool = False  # needs a router per site (``zdrone demo --sites``)
    tls: bool = False  # needs mutual TLS (``zdrone demo --tls``; a router per site has it anyway)
    radio: tuple[str, ...] = ()  # the drone's emulated radio (``--sil-loss 0.2`` ...)
    gs_x: bool = False  # start GS X (in the fleet, not authorized) as a real node
    gcs_a: bool = False  # give GS A a GCS gateway endpoint (udpin on a free port)
    telem2: bool = False  # give the simulator a second MAVLink endpoint (its TELEM2, udpin on a free port)
    fixed_moment: bool = False  # its fault's moment is what the scenario is (``moments()`` gives none to move to)
    operators: str | None = None  # at this moment, start the two operators (``zdrone.sil.operator``) on A's and B's gateways
    consent_ops: str | None = None  # at this moment, start the three operators (``zdrone.sil.consent_ops``)
    x_authorized: bool = False  # X is a third GS authorized for d1 (started, with a GCS gateway, without pairing)
    linger: float = 0.0  # wall seconds the run goes on after the vehicle landed (what happens on the ground)
    plain_router: bool = False  # its attacker holds router passwords only: no --tls, no --sites (no certificate)
    app_signing: bool = False  # GS A's gateway requires signed applications (a key file the launcher writes); B has one
    vehicle_udpin: bool = False  # the companion listens for its autopilot on UDP (PX4's onboard link): the simulator sends to it
    revision_lease: float | None = None  # the fleet's owner lease (s; None: ``fleet init``'s default)

    def own_moment(self) -> str | None:
        """The moment (of ``MOMENTS``) its first fault lands at, None if none matches (or no fault)."""
        if not self.faults:
            return None
        f = self.faults[0]
        return next((m for m, (trig, _) in MOMENTS.items() if trig == f.trigger), None)

    def moments(self) -> tuple[str, ...]:
        """The moments its fault can land at and still be this scenario (none without a fault)."""
        return () if not self.faults or self.fixed_moment or self.own_moment() is None else tuple(MOMENTS)

    def at_moment(self, moment: str) -> "Scenario":
        """The scenario with its faults moved to ``moment``: the faults of its first fault's trigger move,
        their offsets kept relative to the first; at its own moment, the scenario itself. Away from
        it, success is what holds at any moment: the safety invariants, and a completed flight
        whenever no fault is still active when the drone returns (``fault_over_check``)."""
        if moment not in MOMENTS:
            raise ValueError(f"unknown moment {moment!r}: one of {', '.join(MOMENTS)}")
        if moment not in self.moments():
            raise ValueError(f"{self.name}: its fault does not move (moments: {', '.join(self.moments()) or 'none'})")
        if moment == self.own_moment():
            return self
        trigger, after = MOMENTS[moment]
        first = self.faults[0]
        moved = tuple(replace(f, trigger=trigger, after=round(after + f.after - first.after, 3))
                      if f.trigger == first.trigger else f for f in self.faults)
        return replace(self, faults=moved, check=fault_over_check,
                       description=f"{self.description} — the fault moved to {moment}")


_STOP_A = Fault(AIRBORNE, "gsA", signal.SIGSTOP, "GS A goes silent (SIGSTOP)")
_KILL_B = Fault(REGION_ENTERED, "gsB", signal.SIGKILL, "GS B crashes (SIGKILL)")
_RESUME_A = Fault(FAILSAFE_FIRED, "gsA", signal.SIGCONT, "GS A wakes up (SIGCONT)")
RESTART = -1
LINK_DOWN, LINK_UP = -2, -3  # a testbed link (``backhaul``) cut or mended
#: the operator revokes / rotates the target node in flight (``Demo.revise``: the next signed revision
#: on the fleet machine, published through another GS; a revocation restarts the routers on the
#: regenerated files one at a time; a rotation drops the new secret into the node's bundle)
REVOKE, ROTATE = -4, -5
#: the operator revokes the target on the far side of a cut backhaul: published at site 1, only site 1's
#: router restarted on the new files; the target's site (and the drone there) never hears of it
REVOKE_BEHIND_CUT = -6
_HANG_A = Fault(REGION_ENTERED, "gsA", signal.SIGSTOP, "GS A hangs (SIGSTOP) in the overlap", after=0.5)
_WAKE_A = Fault(REGION_ENTERED, "gsA", signal.SIGCONT, "GS A wakes up (SIGCONT) 5 s later", after=5.5)
_RESTART_DRONE = Fault(AIRBORNE, "drone", RESTART, "the companion is killed (SIGKILL) and started again", down=0.3,
                       after=1.0)
_SLOW_RESTART_DRONE = Fault(AIRBORNE, "drone", RESTART, "the companion is killed (SIGKILL), back 1.5 s later",
                            down=1.5, after=1.0)
_SITE1_DOWN = Fault(REGION_ENTERED, "router", RESTART, "site 1's router dies; back 6 s later", down=6.0, after=0.5)
_SITE1_DOWN_ALONE = Fault(AIRBORNE, "router", RESTART, "site 1's router dies before the overlap; back 6 s later",
                          down=6.0, after=0.5)
_BACKHAUL_CUT_EARLY = Fault(BEFORE_GS_A, "backhaul", LINK_DOWN, "the backhaul between the sites is cut before A pairs")
_BACKHAUL_CUT = Fault(AIRBORNE, "backhaul", LINK_DOWN, "the backhaul between the sites is cut in flight")
_REVOKE_B = Fault(RETURNING, "B", REVOKE, "the operator revokes GS B (its host is lost) while B holds authority",
                  after=1.2)
_REVOKE_B_UNCOVERED = Fault(AT_DELIVERY, "B", REVOKE, "the operator revokes GS B while B holds authority at the "
                            "delivery point, outside A's coverage", after=0.5)
_CUT_AT_DELIVERY = Fault(AT_DELIVERY, "backhaul", LINK_DOWN, "the backhaul between the sites is cut while B holds "
                         "authority at the delivery point (only site 2's radio reaches the drone)")
_JAM_SITE1_AT_DELIVERY = Fault(AT_DELIVERY, "site-1", LINK_DOWN, "site 1's radio cannot reach the drone from then on "
                               "(the partition: wherever it flies, only site 2 hears it)")
_REVOKE_B_BEHIND_CUT = Fault(AT_DELIVERY, "B", REVOKE_BEHIND_CUT, "the operator revokes GS B on A's side of the cut "
                             "(site 1 only)", after=0.5)
_ROTATE_A = Fault(AIRBORNE, "A", ROTATE, "the operator rotates GS A's key while A holds authority", after=1.0)
_RESTART_ROUTER = Fault(AIRBORNE, "router", RESTART, "the router is killed and started again 0.8 s later", down=0.8)
#: ``view-truth``: the companion stops this long after both hand-overs (the liars at work from 1 s after them) ...
VIEW_STOP_AFTER_S = 2.0
#: ... for this long
VIEW_STOP_S = 5.0
_STOP_DRONE = Fault(HANDOVERS_DONE, "drone", signal.SIGSTOP, "the companion stops (SIGSTOP)", after=VIEW_STOP_AFTER_S)
_WAKE_DRONE = Fault(HANDOVERS_DONE, "drone", signal.SIGCONT, f"the companion goes on (SIGCONT) {VIEW_STOP_S:g} s later",
                    after=VIEW_STOP_AFTER_S + VIEW_STOP_S)


SCENARIO_TABLE: tuple[Scenario, ...] = (
    Scenario("nominal", "the reference flight", "A->B and B->A in the overlap, landing at home", flight_unaffected),
    Scenario("rogue-no-key",
             "A's stolen router password (no keys): pairs with its own key, sends unsealed and forged-sealed LAND, "
             "replays captured frames; tries a wrong router password",
             "all dropped (unknown_epoch, auth_failed, replay; its pairing fails the tag: pair_refused:bad_mac); flight unaffected",
             check_no_key, rogues=(RogueSpec("no-key", MISSION_STARTED, sim_s=40.0, min_wall=10.0),)),
    Scenario("rogue-unauthorized",
             "GS X (in the fleet, not authorized) pairs and flies, asks for B's link key, publishes on A's key",
             "no answer: the router ACL stops its queries (the drone would refuse them before crypto); flight unaffected",
             check_unauthorized, rogues=(RogueSpec("unauthorized", MISSION_STARTED, sim_s=30.0, min_wall=8.0),), gs_x=True),
    Scenario("link-loss", "GS A goes silent after take-off", "failsafe LAND <= 100 ms after the 3 s threshold",
             check_link_loss, faults=(_STOP_A,)),
    Scenario("gs-crash", "GS B dies as the drone enters the overlap",
             "the hand-over times out, authority stays with A, A brings it home", check_gs_crash, faults=(_KILL_B,)),
    Scenario("router-restart",
             "the router dies in flight (SIGKILL) and is started again on the same endpoint 0.8 s later",
             "every node reconnects by itself; links and authority unchanged, no failsafe; both hand-overs",
             check_router_restart, faults=(_RESTART_ROUTER,)),
    Scenario("gs-hang",
             "GS A, the authority, hangs in the overlap (SIGSTOP for 5 s) and wakes up (SIGCONT)",
             "the emergency hand-over to B (proven link); A learns it is no longer the authority and none of its "
             "commands is forwarded; B hands back to A as usual",
             check_gs_hang, faults=(_HANG_A, _WAKE_A)),
    Scenario("revoke-in-flight",
             "GS B, the authority on the way back, is revoked by a signed fleet revision published in flight",
             "the drone drops B's link and keys, A (covering it) takes over, no failsafe, no command of B after the "
             "revision; routers restarted on the new files without a failsafe; landing at home",
             check_revoke_in_flight, faults=(_REVOKE_B,), fixed_moment=True),
    Scenario("revoke-uncovered",
             "GS B, the authority at the delivery point (no other authorized GS covers it), is revoked in flight",
             "the drone drops B's link and keys; no heir proven in its coverage: its failsafe at once, nobody holds "
             "authority after it, no command of B after the revision; routers restarted on the new files",
             check_revoke_uncovered, faults=(_REVOKE_B_UNCOVERED,), fixed_moment=True),
    Scenario("revoked-alone",
             "two sites; at the delivery point (B holds authority) the network splits: the backhaul is cut, site 1's "
             "radio no longer reaches the drone, and B is revoked on A's side; the fleet's owner lease is "
             f"{REVOKED_ALONE_LEASE_S:g} s",
             "the revision never reaches the drone, and B's own stamps renew nothing: the lease lapses within "
             "the lease of the cut, no heir covers the drone: its failsafe; no command of B forwarded after it",
             check_revoked_alone, faults=(_CUT_AT_DELIVERY, _JAM_SITE1_AT_DELIVERY, _REVOKE_B_BEHIND_CUT), sites=True, fixed_moment=True,
             revision_lease=REVOKED_ALONE_LEASE_S),
    Scenario("lease-stamper",
             "revoked-alone, and GS X's key, router password and certificate (in the fleet, authorized for no drone) "
             "on the drone's side of the split: from the cut on, a stamp signed with X's own key naming the revision "
             f"in force and the drone, every {LEASE_STAMPER_PERIOD_S:g} s, on X's own revision key",
             "X's stamps reach the drone and renew nothing (stamp_refused:unauthorized): B's lease lapses within the "
             "lease of the cut as in revoked-alone, then the failsafe; no command of B forwarded after it",
             check_lease_stamper, faults=(_CUT_AT_DELIVERY, _JAM_SITE1_AT_DELIVERY, _REVOKE_B_BEHIND_CUT),
             rogues=(RogueSpec("lease-stamper", MISSION_STARTED, go=AT_DELIVERY, sim_s=0.0, min_wall=120.0,
                               rate=1.0 / LEASE_STAMPER_PERIOD_S, beside="B"),),
             sites=True, fixed_moment=True, revision_lease=REVOKED_ALONE_LEASE_S),
    Scenario("rotate-in-flight",
             "GS A's static key is rotated by a signed fleet revision while A holds authority",
             "A re-pairs under its new key make-before-break: no failsafe, no emergency hand-over, both hand-overs",
             check_rotate_in_flight, faults=(_ROTATE_A,), fixed_moment=True),
    Scenario("lossy-radio",
             "every radio link loses 20 % of frames at random and delays the rest by 50 ± 20 ms",
             "no false failsafe, the authority link never LOST; both hand-overs; landing at home",
             check_lossy_radio, radio=("--sil-loss", "0.2", "--sil-delay-ms", "50", "--sil-jitter-ms", "20")),
    Scenario("companion-restart",
             "the drone's companion node is killed in flight (SIGKILL) and started again",
             "the vehicle flies on; the node comes back with owner A and its epoch, A re-pairs (fresh keys) within "
             "the loss threshold, shares B's key again; both hand-overs; nobody else gets authority",
             check_companion_restart, faults=(_RESTART_DRONE,)),
    Scenario("site-router-down",
             "two sites (a router each, meshed); the router of A's site dies in the overlap while A holds authority, "
             "and is back 6 s later",
             "the drone moves to site 2's router at once; A is cut off: the emergency hand-over to B (proven), no "
             "failsafe; B hands back to A when the flight returns",
             check_site_router_down, faults=(_SITE1_DOWN,), sites=True),
    Scenario("site-router-down-alone",
             "two sites; the router of A's site dies after take-off, before the overlap (only site 1 in range)",
             "A's link is silent: failsafe LAND <= 100 ms after the 3 s threshold; no hand-over",
             check_site_router_down_alone, faults=(_SITE1_DOWN_ALONE,), sites=True, fixed_moment=True),
    Scenario("backhaul-cut",
             "two sites; the backhaul between their routers is cut before A pairs (before key sharing)",
             "A cannot share B's key: the hand-over is refused cleanly, authority stays with A, which brings the "
             "drone home; no failsafe",
             check_backhaul_cut_early, faults=(_BACKHAUL_CUT_EARLY,), sites=True, fixed_moment=True),
    Scenario("backhaul-cut-late",
             "two sites; the backhaul between their routers is cut after take-off (after key sharing)",
             "both hand-overs still complete (they need no backhaul: each site's radio reaches the drone); "
             "gap 0, no failsafe",
             flight_unaffected, faults=(_BACKHAUL_CUT,), sites=True),
    Scenario("rogue-no-cert",
             "mutual TLS (--tls): with A's stolen password, a client without a certificate, one with another CA's "
             "certificate for A, and one with X's real certificate, in flight",
             "the first two refused at connect; X's certificate as A gets nothing through (ACL: CN and user); "
             "flight unaffected",
             check_no_cert, rogues=(RogueSpec("no-cert", MISSION_STARTED, go=AIRBORNE, sim_s=20.0, min_wall=5.0),),
             tls=True),
    Scenario("failsafe-recover",
             "GS A goes silent after take-off (SIGSTOP), the drone enters its failsafe; A wakes (SIGCONT) and its "
             "operator's standing request (--take-control) asks for control back",
             "failsafe LAND, then LINKED(A, epoch+1) by A's explicit request; the vehicle goes on landing",
             check_failsafe_recover, faults=(_STOP_A, _RESUME_A), gs_a_extra=("--take-control",), fixed_moment=True),
    Scenario("key-injection",
             "B's router password only: a second queryable on backhaul/B/linkkey/* answers A's key-sharing "
             "queries with forged replies (random bytes, a Noise message 2 made with its own key)",
             "A refuses them by their tag (linkkey_reply:bad_mac), takes the real B's key; flight unaffected",
             check_key_injection, rogues=(RogueSpec("key-injection", BEFORE_GS_A, sim_s=1600.0, min_wall=400.0),)),
    Scenario("linkkey-knockout",
             "B's router password only: key-sharing queries to A claiming to be B (message 1 made with its own key) "
             "and junk, 5/s in flight",
             "A refuses them before any crypto (linkkey_refused:bad_mac / malformed), its live link untouched",
             check_linkkey_knockout,
             rogues=(RogueSpec("linkkey-knockout", MISSION_STARTED, go=AIRBORNE, sim_s=80.0, min_wall=15.0, rate=5.0),)),
    Scenario("pair-replay",
             "the drone's router password captures A's pairing message 1 before A starts; A's password replays it "
             "every second in flight",
             "the drone answers with its first message 2 again (pair_repeated): no new key; authority and A's link untouched",
             check_pair_replay, rogues=(RogueSpec("pair-replay", BEFORE_GS_A, go=AIRBORNE, sim_s=48.0, min_wall=12.0),)),
    Scenario("pair-flood",
             "B's private key and router password: >= 2000 valid pairing queries/s for 10 s in flight",
             "refused before any crypto (pair_refused:rate_limited), at most a few answered; telemetry never stops",
             check_pair_flood,
             rogues=(RogueSpec("pair-flood", MISSION_STARTED, go=AIRBORNE, sim_s=0.0, min_wall=10.0, rate=2500.0),)),
    Scenario("uplink-policy",
             "B's private key: pairs as B after both hand-overs and sends 12 dangerous message ids sealed; A's "
             "router password: the same ids unsealed and with a random key, all flight",
             "dropped by the handover authority (not_authority, denied_by_policy) and the security module; "
             "nothing reaches the vehicle",
             check_uplink_policy,
             rogues=(RogueSpec("uplink-unsealed", MISSION_STARTED, go=AIRBORNE, sim_s=100.0, min_wall=10.0),
                     RogueSpec("uplink-sealed", MISSION_STARTED, go=HANDOVERS_DONE, sim_s=0.0, min_wall=1.5))),
    Scenario("gateway-flood",
             "a local process floods GS A's GCS gateway: HEARTBEATs from 320 UDP source ports and garbage, in flight",
             "A keeps flying and counts the refused applications (app_table_full)",
             check_gateway_flood, rogues=(RogueSpec("gateway-flood", MISSION_STARTED, go=AIRBORNE, sim_s=100.0, min_wall=10.0),),
             gcs_a=True),
    Scenario("operator-consent",
             "MAVLink operator control through A's and B's GCS gateways (pymavlink applications) in the overlap: B "
             "asks without consent, then with A's consent, then each takes control with takeover allowed; B "
             "releases back to A and the mission goes on",
             "nothing moves without consent; B in control within the 10 s window after consent and at once with "
             "takeover allowed; no emergency hand-over, no failsafe, landing at home",
             check_operator_consent, operators=GSS_STARTED),
    Scenario("consent-bound",
             "three authorized GSs, an operator application on each gateway, in the overlap: B asks, X asks 1.1 s "
             "later, A's operator consents naming X (refused) then B; B's operator declines X, X asks again; B "
             "allows takeover in its epoch, A takes it, gives it back by consent, then asks again",
             "control goes to B, the requester named; X is not shown while B's request stands nor after its "
             "decline, and never holds authority; an earlier epoch's allow-takeover moves nothing; landing at home",
             check_consent_bound, consent_ops=GSS_STARTED, x_authorized=True),
    Scenario("big-flood",
             "B's router password only: 60 KiB envelopes, pairing and key-sharing queries (20/s each) and 4 MiB "
             "ones (1/s each), from the overlap on (through the hand-over)",
             "the router drops uplink puts and pairing queries over the drone's limits where they enter it (none "
             "reaches the drone) and everything over 64 KiB; A refuses the rest by length (oversize); telemetry never stops",
             check_big_flood,
             rogues=(RogueSpec("big-flood", MISSION_STARTED, go=REGION_ENTERED, sim_s=40.0, min_wall=10.0, rate=20.0),)),
    Scenario("insider-heir",
             "two sites (mutual TLS, meshed); B's own key, router password and certificate (an authorized GS "
             "gone bad): pairs about once a second from take-off on, outside its coverage, sends RETURN_TO_LAUNCH, "
             "asks for control, and once in command ARM and TAKEOFF; A, the authority, hangs (SIGSTOP) after "
             "take-off; watched 3 s on after the landing",
             "never B: the failsafe (or A keeps authority); no authority to B outside its coverage, in the air or "
             "landed, none of B's commands forwarded",
             check_insider_heir, rogues=(RogueSpec("insider-heir", MISSION_STARTED, sim_s=120.0, min_wall=30.0),),
             faults=(Fault(AIRBORNE, "gsA", signal.SIGSTOP, "GS A hangs (SIGSTOP) after take-off"),),
             sites=True, linger=3.0, fixed_moment=True),
    Scenario("key-escrow",
             "B's own key and router password, the drone's password: genuine key-sharing queries to A for link "
             "(drone, A), again and again from take-off to landing; under any secret A hands out, frames to A as "
             "the drone and to the drone as A",
             "A's live link is never replaced (no link_confirmed of a secret it handed out); flight unaffected",
             check_key_escrow,
             rogues=(RogueSpec("key-escrow", MISSION_STARTED, go=AIRBORNE, sim_s=240.0, min_wall=60.0),),
             plain_router=True),
    Scenario("stale-pairing",
             "A's pairing message 1s (recorded in earlier flights, and captured all flight long with the drone's "
             "password) replayed with A's password around a companion restart (killed, back 1.5 s later: A is "
             "re-pairing while it boots)",
             "no replay spends A's pairing tokens (no pair_refused:rate_limited): A re-pairs in time, no failsafe; "
             "both hand-overs",
             check_stale_pairing, faults=(_SLOW_RESTART_DRONE,),
             rogues=(RogueSpec("stale-pairing", BEFORE_GS_A, go=DRONE_RESTARTED, sim_s=24.0, min_wall=6.0),),
             plain_router=True),
    Scenario("local-app",
             "A's gateway requires signed applications (--gcs-signing require, a key the launcher provisions); in the "
             "overlap, with A in control, B's operator asks for control and an unsigned local application on A's "
             "host (a fresh UDP socket, sysid 42) consents, allows takeover, sends LAND, disarm, a mode change, "
             "MISSION_CLEAR_ALL and a consent signed with a guessed key; A's operator's signed application holds the "
             "vehicle meanwhile and resumes the mission",
             "nothing the local application sends moves authority or reaches the vehicle (DENIED / NOT_IN_CONTROL / "
             "MISSION_ACK DENIED, counted; the guessed key dropped); its parameter read answered; the signed "
             "application obeyed; flight unaffected",
             check_local_app, rogues=(RogueSpec("local-app", MISSION_STARTED, go=HANDOVERS_DONE, sim_s=0.0, min_wall=60.0),),
             app_signing=True),
    Scenario("fc-rogue-radio",
             "a radio on the autopilot's TELEM2 (no keys) sends arm, a mode change to LAND and MISSION_CLEAR_ALL once "
             "a second in flight (with --fc-signing off: the control, the same attack on an unsigned autopilot)",
             "the autopilot link is MAVLink-signed: the autopilot obeys and answers none of it; flight unaffected "
             "(--fc-signing off: the autopilot obeys, the flight does not complete)",
             check_fc_rogue_radio,
             rogues=(RogueSpec("fc-radio", MISSION_STARTED, go=AIRBORNE, sim_s=20.0, min_wall=8.0),), telem2=True),
    Scenario("fake-autopilot",
             "a local process on the companion host writes into its UDP vehicle link (the companion listening, as on "
             "PX4's onboard link): a fake autopilot (sysid 7) with positions at B's centre from before the drone "
             "starts; in flight the autopilot's own ids, positions at B's centre and LAND mode, while GS A goes "
             "silent (SIGSTOP)",
             "the drone adopts system 1 only and sends the fake nothing (dropped: before_autopilot, "
             "foreign_endpoint); its position and authority never follow the forged one (no hand-over to B); the "
             "failsafe LAND reaches the real autopilot, which shows it",
             check_fake_autopilot,
             rogues=(RogueSpec("fake-autopilot", BEFORE_DRONE, go=AIRBORNE, sim_s=60.0, min_wall=15.0),),
             faults=(Fault(AIRBORNE, "gsA", signal.SIGSTOP, "GS A goes silent (SIGSTOP)"),),
             vehicle_udpin=True, fixed_moment=True),
    Scenario("view-truth",
             "the fleet's viewer lied to (run it with --view PORT to watch the page): GS A's key rotated in flight; "
             "1 s after both hand-overs, X's key and password (authorized for no drone) and B's own key (with the "
             "viewer's leaked router password) seal pictures for the viewer saying d1 is in its FAILSAFE, held by "
             "them, takeover allowed, a request pending, elsewhere, its link ok and heard 0 s ago, X at 4/s with "
             "bursts, B replaying the drone's signed word from when B held authority; then the companion stops "
             f"(SIGSTOP) for {VIEW_STOP_S:g} s while they go on",
             "the flight's own checks: the safety invariants, both hand-overs, A's rotation taken, X never holding "
             "authority, both liars published, the drone's word captured early and replayed after authority moved; the page (tests/"
             "integration/test_view_truth.py): the owner the drone signed or stale, never X, never B after the "
             "hand-back, no FAILSAFE the drone did not enter, stale within 3.5 s of the stop",
             check_view_truth,
             rogues=(RogueSpec("ops-unauthorized", MISSION_STARTED, go=HANDOVERS_DONE, sim_s=0.0, min_wall=14.0, rate=4.0,
                               args=("--after-go", "1")),
                     RogueSpec("ops-insider", MISSION_STARTED, go=HANDOVERS_DONE, sim_s=0.0, min_wall=14.0, rate=4.0,
                               args=("--after-go", "1"))),
             faults=(_ROTATE_A, _STOP_DRONE, _WAKE_DRONE), fixed_moment=True),
)
SCENARIO_BY_NAME: dict[str, Scenario] = {s.name: s for s in SCENARIO_TABLE}
#: Scenarios that need a router per site.
SCENARIO_SITES: dict[str, bool] = {s.name: s.sites for s in SCENARIO_TABLE}
#: Scenarios that need mutual TLS.
SCENARIO_TLS: dict[str, bool] = {s.name: s.tls for s in SCENARIO_TABLE}
SCENARIOS = tuple(SCENARIO_BY_NAME)
#: The corridor's scenarios (``zdrone.bench.corridordemo``: eight GSs and one drone, the corridor bench's
#: processes): name -> (what happens, what counts as success)
CORRIDOR_SCENARIOS = {
    "corridor": ("8 GSs along 16 km, one drone out and back, links following it",
                 "14 hand-overs, gap 0 ms, never more than 3 links, landed at home"),
    "corridor-gs-down": ("the corridor; D, in the middle, dies 0.5 s after it took authority",
                         "an heir covering the drone takes it, or the failsafe lands it; never more than 3 links"),
}
ATTACK_SCENARIOS = tuple(s.name for s in SCENARIO_TABLE if s.rogues)
assert len(SCENARIOS) == len(SCENARIO_TABLE) and all(
    t in TRIGGERS for s in SCENARIO_TABLE for t in [r.launch for r in s.rogues] + [r.go for r in s.rogues if r.go])


def scenario_help() -> str:
    """The scenario list for ``zdrone demo --help``."""
    width = max(len(s.name) for s in SCENARIO_TABLE)
    lines = ["scenarios:"]
    for s in SCENARIO_TABLE:
        text = textwrap.wrap(f"{s.description}. Success: {s.expected}.", 96 - width)
        lines += [f"  {s.name:<{width}}  {text[0]}", *(f"  {'':<{width}}  {t}" for t in text[1:])]
    for name, (description, expected) in CORRIDOR_SCENARIOS.items():
        text = textwrap.wrap(f"{description}. Success: {expected}.", 96 - width)
        lines += [f"  {name:<{width}}  {text[0]}", *(f"  {'':<{width}}  {t}" for t in text[1:])]
    return "\n".join(lines)
