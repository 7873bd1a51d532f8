"""What the sessions of one ground station share (``StationContext``), the options it runs with
(``CoreOptions``) and the timings of the rules its sessions keep (``gs.session``)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mav

from zdrone.core.fleet import Fleet
from zdrone.core.geometry import Circle
from zdrone.core.keys import Identity
from zdrone.core.linktraffic import LinkTraffic
from zdrone.core.mavlink import FrameCodec
from zdrone.vehicle.report import READ_MSGIDS

from gs.planner import PlannedItem

GCS_COMPID = mav.MAV_COMP_ID_MISSIONPLANNER
#: the messages the station decodes: the vehicle's report (``VehicleReport``), the mission's and the acks
USED_MSGIDS = READ_MSGIDS | {mav.MAVLINK_MSG_ID_MISSION_CURRENT, mav.MAVLINK_MSG_ID_COMMAND_ACK,
                            mav.MAVLINK_MSG_ID_MISSION_REQUEST_INT, mav.MAVLINK_MSG_ID_MISSION_REQUEST,
                            mav.MAVLINK_MSG_ID_MISSION_ACK, mav.MAVLINK_MSG_ID_PARAM_VALUE,
                            mav.MAVLINK_MSG_ID_MISSION_ITEM_REACHED}
#: An unconfirmed HANDOVER_RELEASE is sent again this often (a lossy radio must not make the
#: drone leave the overlap before it hears one).
RELEASE_RESEND_S = 0.25
#: The authority GS pairs again when the drone has been silent this long (and again as often): a
#: restarted companion has lost every key and must have its owner back within the loss threshold.
SILENT_REPAIR_S = 1.0
#: ... and then tries every this often, each try waiting this long for its answer: a companion that
#: comes back is re-paired within this time of its pairing queryable being up (a query to a drone
#: that is down gets no answer; the drone answers a live one in milliseconds).
SILENT_RETRY_S = 0.2
#: ... for this long of the drone's silence; then every ``SILENT_SLOW_RETRY_S`` (a drone out of reach
#: for good, or one whose authority moved on while we missed its word, is not asked five times a second
#: forever; a companion that takes longer than this to come back is re-paired within a second).
SILENT_FAST_S = 10.0
SILENT_SLOW_RETRY_S = 1.0
#: A silent drone's re-pairing (``tick``) is tried every ``SILENT_RETRY_S`` but waits this long for its
#: answer: a loaded companion answering in 0.3 s, asked again at 0.2 s, paid a handshake per question (K =
#: 300: 8-12 per drone); a query no queryable took ends at once (``Linking.pair_unanswered``).
SILENT_PAIR_TIMEOUT_S = 1.0
#: After this long without a word from the drone (our site cut off, our process hung) our view of the
#: authority may be stale: authority may have moved meanwhile. Until the drone's authority status
#: (a beacon, at least once a second) says who holds it, the GS acts on no authority it thinks it has.
STALE_VIEW_S = 1.0
#: A hand-over that failed (timed out: the target was not heard; refused) is tried again this often
#: while the vehicle is still where it should happen: a target that comes back takes authority.
HANDOVER_RETRY_S = 2.0
#: Toward a GS whose key is still being shared, the hand-over waits while the vehicle is inside this
#: fraction of our coverage radius; past it, the hand-over has failed (the vehicle comes home) ...
KEY_WAIT_RADIUS = 0.9
#: A key known to be coming holds the vehicle flying its mission where it is in the overlap (the
#: autopilot's hold mode) for at most this long; the mission resumes just before the release. A
#: restart of the companion costs a pause of the flight, at any speed, instead of the delivery.
#: Known to be coming: the key is on its way to the drone (the other GS's authenticated reply), or
#: the other GS said its old link still looks alive (``live_link``, an unauthenticated error) within
#: ``KEY_COMING_S`` while our own pairing showed, authenticated, that the companion restarted (it
#: had lost our key) within ``RESTART_EVIDENCE_S``.
#: (The hold itself, its phases and timings: ``gs.keyhold``.)
KEY_COMING_S = 2.0
RESTART_EVIDENCE_S = 30.0
#: A failed hand-over commands RTL only if the vehicle is leaving our coverage: farther from our
#: centre than when we released, by at least this much (else it is flying into our coverage and
#: needs nothing but the retry).
LEAVING_M = 5.0
#: A deadline is looked at this long after it: a rule "past T" holds just after T, and a sum of floats
#: may fall a hair short of it.
DEADLINE_SLACK_S = 0.001


@dataclass(frozen=True, slots=True)
class CoreOptions:
    """What the GS core needs of the command line."""

    pair: bool = False
    mission: list[PlannedItem] | None = None
    heartbeat_hz: float = 2.0
    command_rate: float = 0.0
    hysteresis_m: float = 20.0
    cipher: str = "zdrone"
    paper_heartbeat: bool = False
    take_control: bool = False  # after a failsafe, ask for control as soon as our link is proven
    allow_takeover: bool = False  # the operator's standing "allow takeover" (MAVLink operator control)
    seed: bytes = b""  # fresh randomness from the adapter: the jitter of retries and spreads (``gs.mission.jitter``)
    pair_drones: frozenset[str] | None = None  # with ``pair``: only these drones (None: every one)
    missions: dict[str, list[PlannedItem]] | None = None  # a drone's own mission, over ``mission`` (a corridor's two ways)


@dataclass(slots=True)
class StationContext:
    """What the sessions of one station share: its name and sysid, the fleet and key in force (set by
    ``StationCore`` on a revision or a rotation), its options and coverage, and where counts go."""

    name: str
    sysid: int
    fleet: Fleet
    identity: Identity
    opts: CoreOptions
    coverage: Circle | None
    counters: Counter
    codec: FrameCodec
    traffic: LinkTraffic
    #: key-sharing queries out, per owner GS: drone -> deadline (``gs.linking.ASKS_IN_FLIGHT``)
    asks_out: dict = field(default_factory=dict)
