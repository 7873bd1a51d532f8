"""Uplink policy: which MAVLink message ids a ground station may send to the vehicle.

Every frame a GS sends up is classified by its message id alone:

* ``READ_ONLY``: any linked GS may send it. An explicit allowlist (``DEFAULT_READ_ONLY``) of ids
  that neither change the vehicle's state nor disturb a transfer the authority has under way.
* ``AUTHORITY_ONLY``: only the GS holding authority may send it. Every id not listed elsewhere,
  including ids no dialect known here defines, is in this class.
* ``DENIED``: nobody may send it (``DEFAULT_DENIED``), unless the fleet's per-drone policy lists it
  in ``allow``, which makes it authority-only for that drone.

The payload is never parsed: COMMAND_LONG / COMMAND_INT are authority-only even when they carry a
harmless MAV_CMD_REQUEST_MESSAGE, because telling the harmless commands from the others would mean
trusting a decoder on every uplink frame. A fleet that needs more read-only ids lists them in the
drone's ``uplink.read_only_extra``.
"""

from __future__ import annotations

import enum
import functools
import types
from typing import Annotated, Mapping

import msgspec
import msgspec.structs

MAX_MSGID = 0xFFFFFF  # MAVLink 2 message ids are 24 bits

MsgId = Annotated[int, msgspec.Meta(ge=0, le=MAX_MSGID)]


class UplinkClass(enum.Enum):
    """Who may send a message id to the vehicle."""

    READ_ONLY = "read_only"  # any linked GS
    AUTHORITY_ONLY = "authority_only"  # only the GS holding authority
    DENIED = "denied"  # nobody, unless the drone's policy allows it (then authority-only)


#: name -> message id of every read-only id (names as in the MAVLink XML; a unit test checks them).
READ_ONLY_NAMES: dict[str, int] = {
    # Presence of the GCS. The autopilot only notes that a GCS is there. (Its own GCS-loss failsafe
    # may count any GCS's heartbeat; the companion's link-loss failsafe is the one that guards the
    # authority link.)
    "HEARTBEAT": 0,
    # Echoed back by the vehicle; a reply only updates link statistics.
    "PING": 4,
    # Parameter reads. A list request makes the vehicle send every parameter once: bounded, and what
    # every GCS does on connecting. Writes (PARAM_SET, PARAM_EXT_SET, PARAM_MAP_RC) are authority-only.
    "PARAM_REQUEST_READ": 20,
    "PARAM_REQUEST_LIST": 21,
    "PARAM_EXT_REQUEST_READ": 320,
    "PARAM_EXT_REQUEST_LIST": 321,
    # ArduPilot: answered with AUTOPILOT_VERSION, nothing else.
    "AUTOPILOT_VERSION_REQUEST": 183,
}
# Left out on purpose (authority-only, add them per drone with ``read_only_extra`` if wanted):
# * every MISSION_* id, downloads included: the mission protocol runs one transaction at a time per
#   vehicle (PX4), so a MISSION_REQUEST_LIST / MISSION_REQUEST_INT / MISSION_ACK from another GS
#   aborts or confuses an upload the authority has under way;
# * REQUEST_DATA_STREAM: it sets stream rates for every GS on the link;
# * SYSTEM_TIME: PX4 and ArduPilot set their clock from it when they have no GPS time;
# * TIMESYNC: a reply (tc1 != 0) feeds the autopilot's clock-offset estimate for the link, which it
#   applies to externally stamped estimator inputs (vision, mocap, odometry);
# * LOG_REQUEST_LIST / _DATA / _END, FILE_TRANSFER_PROTOCOL: a download occupies the link, there is
#   one session at a time, and the same messages erase, write or end the authority's transfer;
# * COMMAND_LONG / COMMAND_INT, even for MAV_CMD_REQUEST_MESSAGE (the payload is not parsed);
# * FENCE_FETCH_POINT, RALLY_FETCH_POINT, TERRAIN_CHECK: stateless reads, but no GCS needs them
#   from a GS without authority.

#: Ids any linked GS may send by default.
DEFAULT_READ_ONLY: frozenset[int] = frozenset(READ_ONLY_NAMES.values())

#: name -> message id of every id denied to all by default.
DENIED_NAMES: dict[str, int] = {
    "SERIAL_CONTROL": 126,  # raw access to the autopilot's serial ports and system shell
    "SETUP_SIGNING": 256,  # replaces the vehicle's MAVLink signing key
    "DEVICE_OP_WRITE": 11002,  # ArduPilot: raw register writes on the sensor buses (I2C/SPI)
    "SECURE_COMMAND": 11004,  # ArduPilot: bootloader public keys and remote-ID key management
    "CUBEPILOT_FIRMWARE_UPDATE_START": 50004,  # starts a firmware update
}
# FILE_TRANSFER_PROTOCOL stays authority-only, not denied: MAVProxy and QGroundControl fetch
# ArduPilot's parameters (and logs, missions) through it.

#: Ids nobody may send unless the drone's policy lists them in ``allow``.
DEFAULT_DENIED: frozenset[int] = frozenset(DENIED_NAMES.values())

assert not DEFAULT_READ_ONLY & DEFAULT_DENIED


class UplinkPolicy(msgspec.Struct, frozen=True, forbid_unknown_fields=True, dict=True):
    """A drone's uplink policy (fleet field ``uplink``); the default is ``UplinkPolicy()``.

    ``read_only_extra``: more ids any linked GS may send. ``allow``: denied-by-default ids this drone
    accepts nevertheless, from its authority only. ``classify`` costs one dict lookup.
    """

    read_only_extra: list[MsgId] = []
    allow: list[MsgId] = []

    def __post_init__(self) -> None:
        both = sorted(set(self.read_only_extra) & set(self.allow))
        if both:
            raise ValueError(f"message id {both[0]} is in both read_only_extra and allow")
        denied = sorted(set(self.read_only_extra) & DEFAULT_DENIED)
        if denied:
            raise ValueError(f"message id {denied[0]} is denied by default: list it in allow (authority only), "
                             "not in read_only_extra")
        stray = sorted(set(self.allow) - DEFAULT_DENIED)
        if stray:
            raise ValueError(f"message id {stray[0]} in allow is not denied by default "
                             f"(denied: {', '.join(str(i) for i in sorted(DEFAULT_DENIED))})")
        # the table is looked up on the first ``classify``: a fleet holds every drone's policy, and a
        # drone classifies under its own only (a table's place on each of 300 policies was 50 kB a parse)

    def classify(self, msgid: int) -> UplinkClass:
        """The class of ``msgid`` under this policy; any id not listed is ``AUTHORITY_ONLY``."""
        try:
            table = self._table
        except AttributeError:  # the first time
            table = _compile(self)
            msgspec.structs.force_setattr(self, "_table", table)
        return table.get(msgid, UplinkClass.AUTHORITY_ONLY)


    @property
    def is_default(self) -> bool:
        return not self.read_only_extra and not self.allow


def _compile(policy: UplinkPolicy) -> Mapping[int, UplinkClass]:
    """msgid -> class for every id that is not authority-only under ``policy``: one read-only table per
    distinct policy, shared by every drone that has it (a fleet of 300 drones, each node's policy
    parsed by each of the 300 companions of a test host, made 90 000 tables of the same default)."""
    return _table(frozenset(policy.read_only_extra), frozenset(policy.allow))


@functools.lru_cache(maxsize=1024)
def _table(read_only_extra: frozenset[int], allow: frozenset[int]) -> Mapping[int, UplinkClass]:
    table = {i: UplinkClass.DENIED for i in DEFAULT_DENIED - allow}
    table.update((i, UplinkClass.READ_ONLY) for i in DEFAULT_READ_ONLY | read_only_extra)
    return types.MappingProxyType(table)


#: The policy of a drone whose fleet entry has no ``uplink`` field.
DEFAULT_POLICY = UplinkPolicy()
