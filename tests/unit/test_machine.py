"""The machine engine (zdrone.core.machine) on toy machines: lookup, the check of every move, a pair
missing from the table, the log line of a move, settle rules and effects, keyed states."""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from zdrone.core.errors import ProtocolError
from zdrone.core.machine import IllegalTransition, Machine, SettleRow, Table, allowed_states

log = logging.getLogger("tests.toy")


class Door(enum.Enum):
    CLOSED = "closed"
    OPEN = "open"
    LOCKED = "locked"


@dataclass(frozen=True)
class Push:
    now: float


@dataclass(frozen=True)
class Lock:
    now: float


@dataclass(frozen=True)
class Kick:
    now: float


class Toy(Machine):
    """A door: its handlers move it by ``_set_state``; a pair not in the table is ignored (None)."""

    _log = log

    def __init__(self) -> None:
        self.state = Door.CLOSED
        self.pushes = 0

    def handle(self, ev: object) -> str | None:
        row = self._row(TOY, ev)
        if row is None:
            return None  # this machine's outcome for a pair not in the table: ignored
        return row[0](self, ev)

    def _machine_name(self, key: object = None) -> str:
        return "door d1"

    def _push(self, ev: Push) -> str:
        self.pushes += 1
        self._set_state(Door.OPEN if self.state is Door.CLOSED else Door.CLOSED, "pushed")
        return "moved"

    def _lock(self, ev: Lock) -> str:
        self._set_state(Door.LOCKED)
        return "locked"

    def _lock_open(self, ev: Lock) -> str:
        self._set_state(Door.LOCKED, "bolt through the air")  # the row does not allow it: a bug
        return "unreachable"

    def _stay(self, ev: object) -> str:
        self._set_state(self.state)  # staying is no move
        return "stayed"


D = Door
TOY: Table[Door] = {
    (D.CLOSED, Push): (Toy._push, frozenset({D.OPEN})),
    (D.OPEN, Push): (Toy._push, frozenset({D.CLOSED})),
    (D.CLOSED, Lock): (Toy._lock, frozenset({D.LOCKED})),
    (D.OPEN, Lock): (Toy._lock_open, frozenset({D.OPEN})),
    (D.LOCKED, Push): (Toy._stay, frozenset()),
}


def test_the_row_of_state_and_event_type_runs_its_handler():
    t = Toy()
    assert t.handle(Push(0.0)) == "moved" and t.state is Door.OPEN and t.pushes == 1
    assert t.handle(Push(1.0)) == "moved" and t.state is Door.CLOSED
    assert t.handle(Lock(2.0)) == "locked" and t.state is Door.LOCKED
    assert t.handle(Push(3.0)) == "stayed" and t.state is Door.LOCKED and t.pushes == 2


def test_a_pair_missing_from_the_table_is_the_machines_outcome_and_changes_nothing():
    t = Toy()
    before = dict(vars(t))
    assert t.handle(Kick(0.0)) is None  # no row for (CLOSED, Kick): the toy ignores it
    assert vars(t) == before


def test_a_move_the_row_does_not_allow_raises_one_programming_error():
    t = Toy()
    t.handle(Push(0.0))
    with pytest.raises(IllegalTransition, match="door d1: open -> locked is not in the table"):
        t.handle(Lock(1.0))
    assert t.state is Door.OPEN  # not applied
    assert issubclass(IllegalTransition, ProtocolError) and issubclass(IllegalTransition, AssertionError)


def test_every_machine_raises_the_same_error_under_its_own_name():
    from gs.keyhold import IllegalHold
    from gs.linking import IllegalPhase
    from gs.mission import IllegalStage
    from zdrone.core import authority

    assert authority.IllegalTransition is IllegalHold is IllegalPhase is IllegalStage is IllegalTransition


def test_a_move_is_logged_old_to_new_with_the_machines_name_and_reason(caplog):
    t = Toy()
    with caplog.at_level(logging.DEBUG, logger="tests.toy"):
        t.handle(Push(0.0))  # a reason
        t.handle(Push(1.0))
        t.handle(Lock(2.0))  # no reason
        t.handle(Push(3.0))  # staying: no move, no line
    assert [(r.name, r.levelno, r.getMessage()) for r in caplog.records] == [
        ("tests.toy", logging.INFO, "door d1: closed -> open (pushed)"),
        ("tests.toy", logging.INFO, "door d1: open -> closed (pushed)"),
        ("tests.toy", logging.INFO, "door d1: closed -> locked"),
    ]


def test_a_move_outside_any_row_names_the_states_its_own_rule_allows():
    t = Toy()
    with pytest.raises(IllegalTransition):
        t._set_state(Door.LOCKED, allowed=frozenset({Door.OPEN}))
    assert t._set_state(Door.LOCKED, "restored", allowed=frozenset({Door.LOCKED})) and t.state is Door.LOCKED
    assert not t._set_state(Door.LOCKED, allowed=frozenset())  # staying: no move, nothing checked


def test_a_row_may_name_the_one_state_it_goes_to():
    assert allowed_states(Door.OPEN) == frozenset({Door.OPEN})
    assert allowed_states(frozenset({Door.OPEN, Door.CLOSED})) == frozenset({Door.OPEN, Door.CLOSED})


@settings(max_examples=200, deadline=None)
@given(st.lists(st.sampled_from([Push(0.0), Lock(0.0), Kick(0.0)]), max_size=20))
def test_over_any_sequence_the_state_is_one_its_row_allowed_or_unchanged(events):
    t = Toy()
    for ev in events:
        before = t.state
        row = TOY.get((before, type(ev)))
        try:
            t.handle(ev)
        except IllegalTransition:
            assert (before, type(ev)) == (Door.OPEN, Lock)  # the one row whose handler is wrong
            continue
        assert t.state is before or (row is not None and t.state in row[1])


# ------------------------------------------------------------- a machine whose handlers choose
class Lamp(enum.Enum):
    OFF = "off"
    ON = "on"
    BROKEN = "broken"


@dataclass(frozen=True)
class Switch:
    now: float


@dataclass(frozen=True)
class Tick:
    now: float


class Chooser(Machine):
    """A lamp: handlers return (state, outputs); a rule of time alone breaks a lamp on too long;
    the effects say "lit"/"dark" once per change, computed from before and after the step."""

    _log = log
    _log_level = logging.DEBUG

    def __init__(self) -> None:
        self.state = Lamp.OFF
        self.since = 0.0
        self.moves: list[tuple[str, float]] = []

    def handle(self, ev: object) -> list[str]:
        row = self._row(LAMP, ev)
        if row is None:
            raise IllegalTransition(f"{type(ev).__name__} in state {self.state.value}")  # our own event: a bug
        return self._step(row, ev, SETTLE)

    def _move(self, rule: str, new: Lamp, allowed: frozenset[Lamp], now: float) -> None:
        super()._move(rule, new, allowed, now)
        self.moves.append((rule, now))

    def _state_note(self) -> str:
        return f"since {self.since:g}"

    def _before(self) -> Lamp:
        return self.state

    def _effects(self, before: Lamp) -> list[str]:
        if before is self.state:
            return []
        return ["lit"] if self.state is Lamp.ON else ["dark"]

    def _switch(self, ev: Switch) -> tuple[Lamp, list[str]]:
        self.since = ev.now
        return (Lamp.OFF if self.state is Lamp.ON else Lamp.ON), ["click"]

    def _stay(self, ev: Tick) -> tuple[Lamp, list[str]]:
        return self.state, []

    def _burn_out(self, now: float) -> tuple[Lamp, list[str]] | None:
        return (Lamp.BROKEN, ["pop"]) if now - self.since >= 10.0 else None

    def _wrong(self, now: float) -> tuple[Lamp, list[str]] | None:
        return Lamp.OFF, []


L = Lamp
LAMP: Table[Lamp] = {
    (L.OFF, Switch): (Chooser._switch, frozenset({L.ON})),
    (L.ON, Switch): (Chooser._switch, frozenset({L.OFF})),
    (L.OFF, Tick): (Chooser._stay, frozenset({L.OFF})),
    (L.ON, Tick): (Chooser._stay, frozenset({L.ON})),
    (L.BROKEN, Tick): (Chooser._stay, frozenset({L.BROKEN})),
}
SETTLE: tuple[SettleRow[Lamp], ...] = (
    (frozenset({L.ON}), Chooser._burn_out, frozenset({L.BROKEN})),
)


def test_a_chosen_state_is_entered_then_the_settle_rules_then_the_effects(caplog):
    c = Chooser()
    with caplog.at_level(logging.DEBUG, logger="tests.toy"):
        assert c.handle(Switch(1.0)) == ["click", "lit"]
        assert c.handle(Switch(2.0)) == ["click", "dark"]
        assert c.handle(Switch(3.0)) == ["click", "lit"]
        assert c.handle(Switch(20.0)) == ["click", "dark"]  # off before the rule looks: no burn-out
        assert c.handle(Switch(21.0)) == ["click", "lit"]
    assert [r.getMessage() for r in caplog.records] == [
        "Chooser: off -> on (since 1)", "Chooser: on -> off (since 2)", "Chooser: off -> on (since 3)",
        "Chooser: on -> off (since 20)", "Chooser: off -> on (since 21)"]
    assert all(r.levelno == logging.DEBUG for r in caplog.records)
    assert c.moves == [("_switch", 1.0), ("_switch", 2.0), ("_switch", 3.0), ("_switch", 20.0), ("_switch", 21.0)]


def test_a_settle_rule_fires_after_the_handler_whatever_the_event():
    c = Chooser()
    c.handle(Switch(1.0))
    assert c.handle(Tick(5.0)) == [] and c.state is Lamp.ON  # not on for long yet
    assert c.handle(Tick(11.0)) == ["pop", "dark"] and c.state is Lamp.BROKEN  # the rule, then the effects
    assert c.moves[-2:] == [("_stay", 11.0), ("_burn_out", 11.0)]
    with pytest.raises(IllegalTransition, match="Switch in state broken"):
        c.handle(Switch(12.0))  # no row for (BROKEN, Switch): this machine raises


def test_a_chosen_state_outside_its_row_raises_staying_included():
    c = Chooser()
    with pytest.raises(IllegalTransition, match="_wrong chose off in off"):
        c._settle(((frozenset({L.OFF}), Chooser._wrong, frozenset({L.ON})),), 1.0)  # staying, not in the row
    assert c.state is Lamp.OFF and c.moves == []


# ------------------------------------------------------------- keyed states
class Valves(Machine):
    """One table for several parts (a valve per pipe), each its own state."""

    _log = log

    def __init__(self) -> None:
        self.valves = {"a": Door.CLOSED, "b": Door.CLOSED}

    def _machine_name(self, key: object = None) -> str:
        return f"valve {key}"

    def _get_state(self, key: object = None) -> Door:
        return self.valves[key]  # type: ignore[index]

    def _put_state(self, new: Door, key: object = None, now: float | None = None) -> None:
        self.valves[key] = new  # type: ignore[index]

    def push(self, pipe: str) -> bool:
        row = self._row(VALVES, Push(0.0), key=pipe)
        if row is None:
            return False
        row[0](self, pipe)
        return True

    def _open(self, pipe: str) -> None:
        self._set_state(Door.OPEN, "pushed", key=pipe)


VALVES: Table[Door] = {(D.CLOSED, Push): (Valves._open, frozenset({D.OPEN}))}


def test_a_keyed_machine_looks_up_and_moves_each_part_apart(caplog):
    v = Valves()
    with caplog.at_level(logging.INFO, logger="tests.toy"):
        assert v.push("a") and v.valves == {"a": Door.OPEN, "b": Door.CLOSED}
        assert not v.push("a")  # (OPEN, Push) is not in the table: the machine says False
        assert v.push("b") and v.valves == {"a": Door.OPEN, "b": Door.OPEN}
    assert [r.getMessage() for r in caplog.records] == ["valve a: closed -> open (pushed)",
                                                        "valve b: closed -> open (pushed)"]
