"""What "this GS owns the drone" means, once, for every part of the GS.

A GS owns a drone when it holds a live link with it and the drone's own latest word (its authority
status) names this GS as the authority, the drone is not in its failsafe (nobody owns it then), and
that word is current (not ``stale``: the drone has not been silent since). Owning is what the operator
consents as (``gs.opcontrol``); *commanding* is owning with no release of ours standing in the
drone's epoch (``DroneSession.holds_authority``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from zdrone.core.authority import State as HaState

if TYPE_CHECKING:
    from gs.droneview import DroneView


def owns(view: "DroneView", gs: str) -> bool:
    """``gs`` owns the drone of ``view`` (the GS's view of it: link, owner, ha_state, stale)."""
    return view.link is not None and view.owner == gs and view.ha_state is not HaState.FAILSAFE and not view.stale
