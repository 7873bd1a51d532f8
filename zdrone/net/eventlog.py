"""JSONL event logs: one object per line with wall time ``t``; flushed at once so others can tail."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, TextIO


class EventLog:
    """Appends events to a JSONL file (or nowhere)."""

    def __init__(self, path: str | Path | None, node: str) -> None:
        self.node = node
        self._fh: TextIO | None = None
        if path:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(path, "a", buffering=1)

    def write(self, type_: str, **fields: Any) -> dict[str, Any]:
        ev = {"t": round(time.time(), 4), "node": self.node, "type": type_, **fields}
        if self._fh is not None:
            self._fh.write(json.dumps(ev, default=str) + "\n")
        return ev

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None


def read_events(path: str | Path) -> list[dict[str, Any]]:
    """All complete events of a JSONL log (a half-written last line is skipped)."""
    out = []
    for line in Path(path).read_text().splitlines():
        try:
            out.append(json.loads(line))
        except ValueError:
            continue
    return out
