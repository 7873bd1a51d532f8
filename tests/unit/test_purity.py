"""zdrone/core, gs/core.py and the drone's core (zdrone/nodes/drone_core.py and its parts) are sans-IO: it imports no zenoh, socket, threading, asyncio, time (nor their kin)."""

import ast
import subprocess
import sys
from pathlib import Path

import gs
import zdrone.core

CORE = Path(zdrone.core.__file__).parent
#: the ground station's pure parts (its protocol core and mission planner)
GS_PURE = [*(Path(gs.__file__).parent / f for f in ("core.py", "session.py", "droneview.py", "planner.py", "actions.py", "handover.py", "mission.py",
                                                    "linking.py", "keyhold.py", "ownership.py", "opcontrol.py")),
           # and the drone's protocol core: its outputs and its part in the fleet's revisions too
           *(CORE.parent / "nodes" / f for f in ("drone_core.py", "drone_actions.py", "drone_revisions.py", "drone_links.py"))]
FORBIDDEN = {"zenoh", "socket", "threading", "asyncio", "time", "subprocess", "multiprocessing", "select",
             "selectors", "datetime"}


def test_core_sources_import_no_io():
    bad = []
    for path in [*CORE.rglob("*.py"), *GS_PURE]:
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            bad += [f"{path.name}: {n}" for n in names if n.split(".")[0] in FORBIDDEN]
    assert not bad, bad


def test_importing_core_loads_no_zenoh_or_socket():
    code = ("import sys, pkgutil, importlib, zdrone.core as c\n"
            "for m in pkgutil.iter_modules(c.__path__): importlib.import_module('zdrone.core.' + m.name)\n"
            "print(','.join(sorted(n for n in ('zenoh', 'asyncio') if n in sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""
