"""``zdrone bench revoke``'s attribution of commands not forwarded: sent after the drone left the GS
(to another GS, or to its failsafe) apart from lost while the GS held authority."""

from __future__ import annotations

from zdrone.bench.revoke import lost_commands


def test_commands_sent_after_the_drone_left_are_not_lost_commands():
    sent = {"A": {"d1": {"1": 10, "3": 5}, "d2": {"1": 8}},
            "B": {"d1": {"2": 4}, "d2": {}},  # the revoked GS: not counted
            "C": {"d1": {}, "d2": {}}}
    drones = {
        # A: 2 of epoch 1 sent after the hand-over to B (epoch 2 exists); 1 of epoch 3 refused in the failsafe
        "d1": {"forwarded_epochs": {"1:A": 8, "2:B": 3, "3:A": 4}, "in_failsafe": 1},
        # A's one epoch on d2: 1 short with no failsafe refusal: lost while A held authority
        "d2": {"forwarded_epochs": {"1:A": 7}, "in_failsafe": 0},
    }
    got = lost_commands(sent, drones, not_gs="B")
    assert (got["after_it_left"], got["in_epoch"]) == (3, 1)
    assert got["where"] == ["A->d1 epoch 1: 2 (2 after it left to another GS)",
                            "A->d1 epoch 3: 1 (1 after it left to its failsafe)",
                            "A->d2 epoch 1: 1 (while it held authority)"]


def test_the_last_commands_to_a_drone_that_flew_out_of_reach_are_out_of_reach_not_lost():
    """B revoked: a drone A holds flies on out of A's coverage with no heir; A's last command before
    the drone's failsafe went into the air (the testbed's radio stopped it). Only in A's last epoch on
    the drone, and no more than the radio stopped."""
    sent = {"A": {"d1": {"1": 10}, "d2": {"1": 10, "3": 6}, "d3": {"1": 9}}}
    drones = {
        "d1": {"forwarded_epochs": {"1:A": 9}, "in_failsafe": 0, "radio_blocked": {"up:A": 4, "down:A": 9}},
        # epoch 1 is not A's last on d2: a command short there is lost however many the radio stopped
        "d2": {"forwarded_epochs": {"1:A": 9, "2:B": 5, "3:A": 4}, "in_failsafe": 0, "radio_blocked": {"up:A": 1}},
        "d3": {"forwarded_epochs": {"1:A": 8}, "in_failsafe": 0, "radio_blocked": {}},  # the radio stopped nothing
    }
    got = lost_commands(sent, drones, not_gs="B")
    assert (got["out_of_reach"], got["after_it_left"], got["in_epoch"]) == (2, 1, 2)
    assert got["where"] == ["A->d1 epoch 1: 1 (1 out of its reach)",
                            "A->d2 epoch 1: 1 (1 after it left to another GS)",
                            "A->d2 epoch 3: 2 (1 out of its reach, 1 while it held authority)",
                            "A->d3 epoch 1: 1 (while it held authority)"]
