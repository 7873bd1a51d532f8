"""MAVProxy (from PyPI) as an operator runs it on a GS's gateway: its output read as it comes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from tests.waiting import readable


class MavProxy:
    def __init__(self, port: int, cwd: Path, modules: str, sysid: int = 250, cmd: str | None = None) -> None:
        args = [str(Path(sys.executable).parent / "mavproxy.py"), f"--master=udpout:127.0.0.1:{port}",
                f"--source-system={sysid}", f"--default-modules={modules}"] + ([f"--cmd={cmd}"] if cmd else [])
        self.p = subprocess.Popen(args, cwd=cwd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, text=True, start_new_session=True,
                                  env={**os.environ, "HOME": str(cwd)})
        assert self.p.stdout is not None
        os.set_blocking(self.p.stdout.fileno(), False)
        self.out: list[str] = []

    def wait_for(self, needle: str, timeout: float) -> bool:
        """Read MAVProxy's output, waiting on it, until a line holds ``needle`` or ``timeout`` passes."""
        assert self.p.stdout is not None
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            line = self.p.stdout.readline()
            if line:
                self.out.append(line)
                if needle in line:
                    return True
                continue
            if self.p.poll() is not None:
                return False
            readable([self.p.stdout], min(left, 1.0))
        return False

    def type(self, cmd: str) -> None:
        """The operator types at MAVProxy's prompt."""
        assert self.p.stdin is not None
        self.p.stdin.write(cmd + "\n")
        self.p.stdin.flush()

    def text(self) -> str:
        return "".join(self.out)

    def stop(self) -> None:
        os.killpg(self.p.pid, signal.SIGTERM)
        try:
            self.p.wait(5)
        except subprocess.TimeoutExpired:  # MAVProxy's own threads may ignore SIGTERM
            os.killpg(self.p.pid, signal.SIGKILL)
            self.p.wait(5)
