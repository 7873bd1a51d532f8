"""TESTBED: the live view of ``zdrone demo``: a rich panel (position, authority, links, the last
events) when on a terminal, plain event lines otherwise."""

from __future__ import annotations

from collections import deque
from typing import Any, Sequence

from zdrone.core.geometry import GeoPoint
from zdrone.core.records import AnyRecord, AuthorityMoved, DroneStatus, Failsafe, fields_of, record_type
from zdrone.core.reference import HOME


def describe(ev: AnyRecord) -> str:
    """One line of the live view for a drone event."""
    t = record_type(ev)
    if isinstance(ev, AuthorityMoved):
        return f"authority {ev.from_} -> {ev.to} (epoch {ev.epoch}, {ev.kind})"
    if isinstance(ev, Failsafe):
        return f"FAILSAFE {ev.action}: {ev.reason} ({ev.detect_to_command_ms or 0:.0f} ms after threshold)"
    fields = fields_of(ev)
    if "detail" in fields:
        return f"{t}: {fields['detail']}"
    if "gs" in fields:
        return f"{t}: {fields['gs']}" + (f" ({fields['reason']})" if "reason" in fields else "")
    return t


class LiveView:
    """A rich live panel when on a terminal; plain event lines otherwise."""

    def __init__(self, scenario: str, enabled: bool, quiet: bool = False) -> None:
        self.scenario = scenario
        self.enabled = enabled and not quiet
        self.quiet = quiet
        self.lines: deque[str] = deque(maxlen=200)  # the last lines only: the view's cost stays flat
        self._live: Any = None
        self._t0: float | None = None

    def __enter__(self) -> "LiveView":
        if self.enabled:
            from rich.live import Live

            self._live = Live(self._render(None, 0.0), refresh_per_second=4, transient=False)
            self._live.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._live is not None:
            self._live.__exit__(*exc)

    def event(self, t: float, text: str) -> None:
        if self._t0 is None:
            self._t0 = t
        line = f"{t - self._t0:7.2f}s  {text}"
        self.lines.append(line)
        if not self.enabled and not self.quiet:
            print(line, flush=True)

    def update(self, status: DroneStatus | None, elapsed: float) -> None:
        if self._live is not None:
            self._live.update(self._render(status, elapsed))

    def _render(self, st: DroneStatus | None, elapsed: float) -> Any:
        from rich.console import Group
        from rich.table import Table

        top = Table(title=f"zdrone demo — {self.scenario} — {elapsed:5.1f} s", show_header=False, expand=True)
        top.add_column(style="bold")
        top.add_column()
        pos = st.position if st else None
        if pos:
            n_e = _ne(pos)
            top.add_row("position", f"{pos[0]:.6f}, {pos[1]:.6f}  alt {pos[2]:.1f} m  ({n_e[1]:+.0f} m east of A)")
        if st is None:  # no status yet
            top.add_row("authority", "None (epoch None, None)")
            top.add_row("vehicle", "disarmed  mode None  region no")
        else:
            top.add_row("authority", f"{st.owner} (epoch {st.epoch}, {st.state.value})"
                        + (f" -> {st.pending_to}" if st.pending_to else ""))
            top.add_row("vehicle", f"{'ARMED' if st.armed else 'disarmed'}  mode {st.mode}  region {'yes' if st.in_region else 'no'}")
        links = Table(title="links (TBM)", expand=True)
        for col in ("GS", "state", "silence s", "opened", "sent", "dropped"):
            links.add_column(col)
        for gs, ln in (st.links if st else {}).items():
            links.add_row(gs, ln.state.value, f"{ln.since_last:.2f}", str(ln.opened), str(ln.sent),
                          ", ".join(f"{k}={v}" for k, v in ln.dropped.items()) or "-")
        ev = Table(title="events", show_header=False, expand=True)
        ev.add_column()
        for line in list(self.lines)[-10:]:
            ev.add_row(line)
        return Group(top, links, ev)


def _ne(pos: Sequence[float]) -> tuple[float, float]:
    from zdrone.core.geometry import ne_of

    return ne_of(HOME, GeoPoint(pos[0], pos[1]))
