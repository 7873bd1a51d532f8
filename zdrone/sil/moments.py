"""TESTBED: the moments of a flight a scenario ties its attackers and faults to (the launcher fires
each when the drone's or GS A's log shows it), and the moments a scenario's fault can be moved to."""

from __future__ import annotations

#: Moments of the flight at which an attacker is started, told to attack, or a fault is injected.
BEFORE_GS_A = "before_gs_a"  # after the drone and GS B are up, before GS A starts (and pairs)
MISSION_STARTED = "mission_started"  # GS A's mission started (the drone is taking off)
AIRBORNE = "airborne"  # armed and above 15 m
REGION_ENTERED = "region_entered"  # first entry into the hand-over region
HANDOVERS_DONE = "handovers_done"  # both hand-overs done: authority back at A, drone still in the overlap
FAILSAFE_FIRED = "failsafe_fired"  # the drone entered its failsafe
HANDOVER_STARTED = "handover_started"  # the drone took the first release (the hand-over A->B begins)
RETURNING = "returning"  # on the way back: the first entry into the hand-over region after the delivery point
AT_DELIVERY = "at_delivery"  # first near the delivery point (only B's coverage; B holding authority)
DRONE_RESTARTED = "drone_restarted"  # a fault restarted the drone's companion (just started again)
BEFORE_DRONE = "before_drone"  # the simulator is up, the drone's companion not yet started
#: Every GS is up with its GCS gateway (not a moment of the flight: when operators' applications start,
#: so that a loaded host's slow start of their process never makes them late for the flight).
GSS_STARTED = "gss_started"
TRIGGERS = (BEFORE_DRONE, BEFORE_GS_A, MISSION_STARTED, AIRBORNE, REGION_ENTERED, HANDOVERS_DONE, FAILSAFE_FIRED, HANDOVER_STARTED,
            RETURNING, AT_DELIVERY, DRONE_RESTARTED)
#: The moments of the flight a scenario's fault can be moved to (``zdrone demo --moment``, ``zdrone bench
#: sweep``): name -> (trigger, wall seconds after it).
MOMENTS: dict[str, tuple[str, float]] = {
    "before_overlap": (AIRBORNE, 0.5),  # climbing out near home, only A's coverage
    "in_overlap": (REGION_ENTERED, 0.5),  # inside both coverages, before the hand-over
    "handover": (HANDOVER_STARTED, 0.0),  # as the drone takes A's release
    "way_back": (RETURNING, 0.5),  # back in the overlap after the delivery, B holding authority
}
