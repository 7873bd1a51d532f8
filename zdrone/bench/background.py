"""A demo flight flown in a thread of its own while a bench samples it from the main thread."""

from __future__ import annotations

import threading
from typing import Any


class BackgroundFlight:
    """``demo.run()`` in a daemon thread (the thread owns the run's processes); ``result()`` gives
    its result, or raises in the caller what the flight raised."""

    def __init__(self, demo: Any, name: str) -> None:
        self._result: dict[str, Any] = {}
        self._failure: list[BaseException] = []
        self._thread = threading.Thread(target=self._fly, args=(demo,), name=name, daemon=True)

    def _fly(self, demo: Any) -> None:
        try:
            self._result.update(demo.run())
        except BaseException as exc:  # noqa: BLE001 - carried to the caller
            self._failure.append(exc)

    def start(self) -> "BackgroundFlight":
        self._thread.start()
        return self

    def is_alive(self) -> bool:
        return self._thread.is_alive()

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

    def result(self) -> dict[str, Any]:
        """The flight's result once it ended; what it raised, raised here."""
        if self._failure:
            raise self._failure[0]
        return self._result
