"""What a ground station knows of one drone: the facts its session (``gs.session``) keeps and its
sub-machines read (``gs.opcontrol``, ``gs.mission``, ``gs.ownership``), and the operator's one-line
picture of them (``view_line``)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from zdrone.core import wire
from zdrone.core.authority import State as HaState
from zdrone.core.envelope import SecureLink
from zdrone.core.geometry import GeoPoint
from zdrone.core.linkslot import LinkSlot
from zdrone.core.tbm import LinkState
from zdrone.vehicle.fix import PositionFix
from zdrone.vehicle.modes import mode_name
from zdrone.vehicle.report import VehicleReport

from gs.handover import Handover
from gs.keyhold import KeyHold


@dataclass(slots=True)
class DroneView(VehicleReport):
    """What this GS knows of one drone: what its vehicle reports (the base, ``VehicleReport``:
    position fix, armed, mode, autopilot, landed state, pre-arm health, texts) and its authority as
    the drone's own status last said it."""

    name: str
    sysid: int
    link: SecureLink | None = None  # the live link (``slot.live``)
    slot: LinkSlot = field(default_factory=LinkSlot)
    hold: KeyHold | None = None  # the vehicle held for a key (one per epoch, ``gs.keyhold``)
    mission_seq: int | None = None
    owner: str | None = None
    epoch: int = 0
    ha_state: HaState | None = None
    pending_to: str | None = None
    fc_signed: bool | None = None  # the drone's link to its autopilot is MAVLink-signed (None: not said)
    attest: wire.AuthorityAttestation | None = None  # the drone's newest signed word on its authority, as it came
    handover: Handover = field(default_factory=lambda: Handover(""))  # our release, in the current epoch
    stale: bool = False  # the drone was silent: our view of the authority waits for its status
    commands_sent: Counter = field(default_factory=Counter)  # per epoch
    last_command: float | None = None
    last_take_control: float | None = None
    takeover: bool = False  # the owner allows takeover (the drone's AuthorityStatus)
    takeover_to: str | None = None  # ... for this GS only (a consent's window); None: any
    switching: bool = False  # our rotated key's pairing made a new key live: the drone has not spoken under it yet
    position_input: int = 0  # the session's input number of the newest position report
    ours_from_input: int = 0  # ... of the status that made the drone ours (a position before it does not count)
    kept_key_at: float | None = None  # the drone's last message 2 saying it still holds our key (``_silence``)

    def _silence(self, now: float) -> float:
        """Since the drone's last sign of life: a frame on our link, or a message 2 saying it holds our key."""
        since = self.link.tbm.since_last(now) if self.link is not None else float("inf")
        return since if self.kept_key_at is None else min(since, max(0.0, now - self.kept_key_at))

    @property
    def position(self) -> GeoPoint | None:
        """Where the vehicle is, None while its autopilot has no position of its own (``PositionFix``)."""
        return self.fix.position

    @position.setter
    def position(self, value: GeoPoint | None) -> None:
        """A new report of the vehicle's position (heard after whatever came before it)."""
        self.fix = PositionFix()
        self.fix.reported = value
        self.position_input = max(self.position_input, self.ours_from_input) + 1


def view_line(gs: str, drone: str, v: DroneView, now: float) -> str:
    """One drone as this GS sees it: how old its last report is and whether this GS holds its
    authority. A drone not heard for the TBM's DEGRADED threshold is shown as STALE with the age of
    what is shown (its authority, position, state are as of then, not now), never as a live line."""
    assert v.link is not None
    age = v.link.tbm.since_last(now)
    state = v.link.tbm.state(now)
    ours = "this GS" if v.owner == gs else "not this GS"
    authority = f"authority {v.owner} (epoch {v.epoch}, {v.ha_state.value if v.ha_state else 'unknown'}), {ours}"
    pos = (f"{v.position.lat:.6f},{v.position.lon:.6f} alt {v.position.alt:5.1f} m" if v.position
           else f"position unknown ({v.fix.unknown_because})")
    vehicle = f"{'ARMED' if v.armed else 'disarmed'} {mode_name(v.autopilot, v.custom_mode)} | mission item {v.mission_seq}"
    link = f"link rx {v.link.opened} tx {v.link.sent} drops {sum(v.link.drops.values())}"
    if v.link.tbm.last_seen is None:
        return f"gs {gs} | {drone}: nothing heard yet ({age:.1f} s since the link was made) | {link}"
    if state is LinkState.OK:
        return f"gs {gs} | {drone}: report {age:.1f} s old | {authority} | {pos} | {vehicle} | {link}"
    since = "may have moved since" if v.owner == gs else "may have changed"
    return (f"gs {gs} | {drone}: STALE, last report {age:.1f} s ago (link {state.value}): as of then {authority} "
            f"(it {since}) | last position {pos} | was {vehicle} | {link}")
