"""The drone's authority state on disk: who holds authority in which epoch, written on every change.

A companion computer may reboot in flight. Its link keys die with it (they are never written down),
but the authority must not: the restarted node comes back with the owner and epoch it had, and that
owner must re-pair (fresh keys, so no nonce is ever reused under a key). On the ground too: the epoch
goes on and the saved owner pairs back first (``DroneCore.restore``), so the file is kept when the
node stops; ``clear`` is for a fleet that starts anew. The file sits beside the
node's secret (``secrets/<drone>.authority.json``, mode 0600; under systemd in the service's state
directory, ``$ZDRONE_STATE_DIR/<drone>.authority.json``, as ``zdrone service`` sets it, the bundle
staying read-only) and is replaced atomically: written to
a temporary file, fsync'ed, renamed over the old one, and the directory fsync'ed, so a crash at any
moment leaves either the old state or the new one, never a torn file.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass
from pathlib import Path

from zdrone.fleet.files import fleet_path, write_durably

log = logging.getLogger(__name__)

#: where the authority state goes instead of beside the secret (the unit ``zdrone service`` writes sets it)
STATE_DIR_ENV = "ZDRONE_STATE_DIR"


@dataclass(frozen=True, slots=True)
class SavedAuthority:
    owner: str | None
    epoch: int
    state: str


class AuthorityStore:
    """Reads and writes one drone's ``SavedAuthority``."""

    def __init__(self, fleet: str | Path, drone: str) -> None:
        state_dir = os.environ.get(STATE_DIR_ENV)
        base = Path(state_dir) if state_dir else fleet_path(fleet).parent / "secrets"
        self.path = base / f"{drone}.authority.json"
        self._last: SavedAuthority | None = None

    def load(self) -> SavedAuthority | None:
        """The state saved before a restart, or None (none, or unreadable: logged, not trusted)."""
        try:
            raw = json.loads(self.path.read_text())
            saved = SavedAuthority(raw["owner"], int(raw["epoch"]), str(raw["state"]))
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError) as exc:
            log.warning("%s: unreadable authority state, ignored: %s", self.path, exc)
            return None
        self._last = saved
        return saved

    def save(self, saved: SavedAuthority) -> None:
        """Write ``saved`` durably if it changed (atomic replace + fsync of file and directory)."""
        if saved == self._last:
            return
        write_durably(self.path, json.dumps({"owner": saved.owner, "epoch": saved.epoch, "state": saved.state}).encode())
        self._last = saved

    def clear(self) -> None:
        """Forget the saved state (nothing to come back to)."""
        try:
            self.path.unlink()
        except FileNotFoundError:
            pass
        self._last = None
