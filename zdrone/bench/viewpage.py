"""The page of ``zdrone view`` as ``zdrone bench view`` opens it: headless Chromium (Debian's, through
Playwright, launched as ``tests/integration/test_view.py`` launches it: its own profile, every request
off the page's own host refused and counted), the probe the fleet and attack parts add to the page to
stamp each picture event it gets (``STREAM_PROBE``), and the p50/p95/max the parts report timings in.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from zdrone.bench.revoke import percentile
from zdrone.core.errors import ConfigError

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--no-first-run", "--disable-sync"]
#: Every picture event: when it arrived, when the page had rendered it (the next task after every
#: listener ran), the server's time of its snapshot, its size.
STREAM_PROBE = """
window.__pictures = [];
window.__lastPicture = null;
(() => {
  const Original = window.EventSource;
  window.EventSource = class extends Original {
    constructor(url, init) {
      super(url, init);
      this.addEventListener('picture', (ev) => {
        const got = Date.now() / 1000;
        const at = ev.data.lastIndexOf('"server_time":');
        const server = at < 0 ? null : parseFloat(ev.data.slice(at + 14));
        const size = ev.data.length;
        window.__lastPicture = ev.data;
        setTimeout(() => window.__pictures.push([got, Date.now() / 1000, server, size]), 0);
      });
    }
  };
})();
"""


def start_in_order(cmds: dict[str, list[str]], ready: dict[str, str], d: Path, logs: dict[str, Any],
                   procs: dict[str, Any]) -> None:
    """Start each command of ``cmds`` in order (its output in ``logs[name]``, ``d/<name>.log``), waiting
    for the line ``ready`` names for it, if any (``RuntimeError`` if it never comes)."""
    import subprocess

    from zdrone.bench.scale import _wait_line
    from zdrone.sil.procs import spawn

    for name, cmd in cmds.items():
        procs[name] = spawn(cmd, stdout=logs[name], stderr=subprocess.STDOUT)
        if name in ready and _wait_line(d / f"{name}.log", ready[name], 30, procs[name]) is None:
            raise RuntimeError(f"{name} did not start; see {d / f'{name}.log'}")


def _stats(values: list[float], scale: float = 1.0, digits: int = 1) -> dict[str, float | None]:
    s = sorted(values)
    if not s:
        return {"p50": None, "p95": None, "max": None}
    return {"p50": round(percentile(s, 50) * scale, digits), "p95": round(percentile(s, 95) * scale, digits),
            "max": round(s[-1] * scale, digits)}


class Browser:
    """Headless Debian Chromium through Playwright, as the view's test launches it."""

    def __init__(self, profile: Path) -> None:
        try:
            from playwright.sync_api import sync_playwright
        except ImportError:
            raise ConfigError("bench view: Playwright is not installed (make venv)") from None
        if not os.path.exists(CHROMIUM):
            raise ConfigError(f"bench view: {CHROMIUM} not found (make venv installs Debian's chromium)")
        self._pw = sync_playwright().start()
        self.context = self._pw.chromium.launch_persistent_context(
            str(profile), executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True,
            viewport={"width": 1400, "height": 1000})
        self.outside: list[str] = []

    def open(self, base: str, init_script: str) -> Any:
        """A page on ``base`` (every request elsewhere refused and counted) with ``init_script``."""
        def gate(route: Any) -> None:
            if route.request.url.startswith(base + "/"):
                route.continue_()
            else:
                self.outside.append(route.request.url)
                route.abort()

        page = self.context.new_page()
        page.route("**/*", gate)
        page.add_init_script(init_script)
        page.goto(base + "/")
        page.wait_for_selector("#conn[data-state=live]", timeout=30_000)
        return page

    def close(self) -> None:
        try:
            self.context.close()
        finally:
            self._pw.stop()
