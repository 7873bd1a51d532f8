"""Test-wide settings: hypothesis without per-example deadlines (CI machines are shared and loaded;
speed targets live in ``zdrone bench``, not in timed tests); every event log strict (an event that
fits no record is an error, in the tests and in every node process they start); faulthandler on in
every process the tests start (a crash leaves its stacks in that process's output); the longest
flights first, then the slow tests (process flights, benches), so that under ``pytest -n`` the quick ones fill the gaps at the end."""

import os

import pytest
from hypothesis import settings

os.environ.setdefault("ZDRONE_STRICT_EVENTS", "1")
os.environ.setdefault("PYTHONFAULTHANDLER", "1")

settings.register_profile("zdrone", deadline=None)
settings.load_profile("zdrone")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    # the longest flights (minutes of wall time, little CPU) before every other slow one: under -n each
    # starts at once on a worker of its own while the others share the CPU, instead of closing the run
    items.sort(key=lambda item: (item.get_closest_marker("longest") is None,
                                 item.get_closest_marker("slow") is None))  # stable: file order otherwise
