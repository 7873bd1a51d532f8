"""The drone's persisted authority state: atomic, private, kept across restarts."""

from __future__ import annotations

import stat

from zdrone.fleet.files import init_fleet
from zdrone.net.authstore import AuthorityStore, SavedAuthority


def test_saved_state_survives_and_is_private(tmp_path):
    init_fleet(tmp_path)
    s = AuthorityStore(tmp_path, "d1")
    assert s.load() is None
    s.save(SavedAuthority("A", 3, "linked"))
    assert AuthorityStore(tmp_path, "d1").load() == SavedAuthority("A", 3, "linked")
    assert stat.S_IMODE(s.path.stat().st_mode) == 0o600 and not s.path.with_suffix(".tmp").exists()
    s.clear()
    assert AuthorityStore(tmp_path, "d1").load() is None


def test_a_torn_or_foreign_file_is_not_trusted(tmp_path):
    init_fleet(tmp_path)
    s = AuthorityStore(tmp_path, "d1")
    s.path.write_text('{"owner": "A", "ep')
    assert s.load() is None
    s.path.write_text('{"owner": "A"}')
    assert s.load() is None
