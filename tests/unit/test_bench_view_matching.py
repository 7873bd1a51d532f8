"""bench view's matching of the drone's hand-over records to the page's owner changes."""

from zdrone.bench.view import match_changes, owner_changes


def test_owner_changes_keep_only_changes_of_the_drone():
    seen = [[1.0, "d1", ""], [1.1, "d1", "A"], [1.2, "d2", "B"], [1.3, "d1", "A"], [2.0, "d1", "B"], [2.1, "d1", None]]
    assert owner_changes(seen, "d1") == [(1.0, ""), (1.1, "A"), (2.0, "B"), (2.1, "")]


def test_each_record_matches_the_next_change_to_its_owner_in_order():
    shown = [(10.05, "B"), (10.2, ""), (10.3, "B"), (20.1, "A"), (30.2, "B")]
    delays = match_changes([(10.0, "B"), (20.0, "A"), (30.0, "B"), (40.0, "A")], shown)
    assert [None if d is None else round(d, 3) for d in delays] == [0.05, 0.1, 0.2, None]  # the last never shown


def test_a_change_shown_before_the_record_counts_negative_not_skipped():
    assert [round(d, 3) for d in match_changes([(5.0, "B")], [(4.9, "B")])] == [-0.1]
