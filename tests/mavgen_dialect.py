"""A Python MAVLink dialect built by pymavlink's own generator (mavgen) from XML text: what a GCS
built from today's definitions speaks (tests of the operator-control codec and of the consent flow)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from pymavlink.generator import mavgen


def generated_dialect(xml_text: str, folder: Path, name: str) -> ModuleType:
    """The module mavgen makes from ``xml_text`` in ``folder``, imported as ``name`` (in ``sys.modules``
    until the caller pops it)."""
    xml = folder / f"{name}.xml"
    xml.write_text(xml_text)
    out = folder / name
    mavgen.mavgen(mavgen.Opts(str(out), wire_protocol="2.0", language="Python3", validate=False), [str(xml)])
    path = Path(str(out) + ".py") if not out.exists() else out
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod
