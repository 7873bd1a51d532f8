"""The simulator's parts reach their autopilot only through the narrow interface each declares (a
``Protocol`` in its own module), and the autopilot provides every member of each."""

import ast
import inspect
from pathlib import Path

import pytest

from zdrone.core.reference import HOME
from zdrone.vehicle.sim import SimAutopilot
from zdrone.vehicle.sim import commands, gcslink, mission, telemetry

PARTS = [(gcslink, gcslink.LinkAutopilot), (mission, mission.MissionAutopilot),
         (commands, commands.CommandedAutopilot), (telemetry, telemetry.ReportedAutopilot)]


def _reached(module) -> set[str]:
    """The attributes a module reads or writes on its autopilot (``ap.x`` and ``self.ap.x``)."""
    names = set()
    for node in ast.walk(ast.parse(Path(module.__file__).read_text())):
        if isinstance(node, ast.Attribute):
            v = node.value
            if isinstance(v, ast.Name) and v.id == "ap":
                names.add(node.attr)
            elif isinstance(v, ast.Attribute) and v.attr == "ap" and isinstance(v.value, ast.Name) and v.value.id == "self":
                names.add(node.attr)
    return names


def _members(proto) -> set[str]:
    own = {n for n, _ in inspect.getmembers(proto) if not n.startswith("_")}
    return own | set(proto.__annotations__)


@pytest.mark.parametrize("module, proto", PARTS, ids=[m.__name__.rsplit(".", 1)[1] for m, _ in PARTS])
def test_each_part_reaches_only_its_declared_interface(module, proto):
    declared = _members(proto)
    assert _reached(module) <= declared, sorted(_reached(module) - declared)
    assert declared <= _reached(module), sorted(declared - _reached(module))  # and declares nothing it never uses


@pytest.mark.parametrize("module, proto", PARTS, ids=[m.__name__.rsplit(".", 1)[1] for m, _ in PARTS])
def test_the_autopilot_provides_every_interface(module, proto):
    ap = SimAutopilot(HOME)
    missing = [n for n in _members(proto) if not hasattr(ap, n)]
    assert not missing, missing


def test_no_part_writes_the_autopilot():
    """The parts steer by ``ap.guidance`` and call the autopilot's methods; none assigns to it."""
    for module, _ in PARTS:
        for node in ast.walk(ast.parse(Path(module.__file__).read_text())):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(
                node, (ast.AugAssign, ast.AnnAssign)) else []
            for t in targets:
                if isinstance(t, ast.Attribute) and isinstance(t.value, (ast.Name, ast.Attribute)):
                    owner = t.value
                    is_ap = (isinstance(owner, ast.Name) and owner.id == "ap") or (
                        isinstance(owner, ast.Attribute) and owner.attr == "ap")
                    assert not is_ap, f"{module.__name__}:{node.lineno} writes ap.{t.attr}"
