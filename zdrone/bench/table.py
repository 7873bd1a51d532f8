"""Printing bench results: a rich table for people, JSON for tools."""

from __future__ import annotations

import json
import sys
from typing import Any, Sequence

from rich.console import Console
from rich.table import Table


def print_table(title: str, columns: Sequence[str], rows: Sequence[Sequence[Any]], caption: str = "") -> None:
    table = Table(title=title, caption=caption or None)
    for i, col in enumerate(columns):
        table.add_column(col, justify="left" if i == 0 else "right")
    for row in rows:
        table.add_row(*(_fmt(v) for v in row))
    Console(file=sys.stdout, width=max(100, Console().width)).print(table)


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:,.2f}"
    return str(v)


def print_json(obj: Any) -> None:
    sys.stdout.write(json.dumps(obj, indent=2) + "\n")


class ProgressLine:
    """One live status line on stderr while a bench runs (nothing when ``enabled`` is false)."""

    def __init__(self, enabled: bool) -> None:
        self._p: Any = Console(stderr=True).status("") if enabled else None
        if self._p is not None:
            self._p.start()

    def say(self, text: str) -> None:
        if self._p is not None:
            self._p.update(text)

    def close(self) -> None:
        if self._p is not None:
            self._p.stop()
