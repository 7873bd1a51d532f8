"""BENCH HARNESS ONLY: run a drone or GS node with a measurement cipher (plain, Fernet).

``python -m zdrone.harness drone|gs [the usual options] --cipher fernet [--paper-heartbeat]``.
This is the only way to build a node with a cipher other than zdrone's: the ``zdrone drone`` and
``zdrone gs`` commands have no such option, and ``SecureLink`` refuses the others unless
``enable_bench_ciphers()`` was called in the process (see ``zdrone.core.envelope``).
"""

from __future__ import annotations

import argparse
import sys

from zdrone.core.envelope import enable_bench_ciphers


def main(argv: list[str] | None = None) -> int:
    from zdrone import cli, commands
    from zdrone.crashes import stacks_on_crash

    stacks_on_crash()  # a crash leaves every thread's stack in the node's log
    enable_bench_ciphers()
    p = argparse.ArgumentParser(prog="python -m zdrone.harness", description="bench harness: nodes with measurement ciphers")
    p.add_argument("-v", "--verbose", action="count", default=0)
    sub = p.add_subparsers(dest="command", required=True)
    commands.add_drone(sub, bench=True)
    commands.add_gs(sub, bench=True)
    args = p.parse_args(argv)
    return cli.run_parsed(args)


if __name__ == "__main__":
    sys.exit(main())
