"""The project's errors, each kind in one place (as h11 has ``LocalProtocolError`` / ``RemoteProtocolError``).

* **User errors** (``UserError``): bad configuration files (``ConfigError``) or command-line input
  (``UsageError``). The ``zdrone`` command prints them as one line saying what and where, exit 2.
* **Protocol errors** (``ProtocolError``): our own code asked a protocol machine for a step it does not
  have, or a handler moved it where its table does not allow (``machine.IllegalTransition``, one class
  for every machine), or a cipher it must not use (``envelope.DowngradeRefused``): programming errors,
  raised. What a *peer* sends is never raised: it is dropped with a counted reason, or answered with a
  reject message.
"""

from __future__ import annotations


class UserError(Exception):
    """Something the user gave us is unusable; ``str()`` is one line: where and what."""


class ConfigError(UserError, ValueError):
    """A configuration file (fleet, secret, router config) or connection is unusable."""


class UsageError(UserError):
    """Bad command-line input."""


class ProtocolError(RuntimeError):
    """Our own code broke a protocol's rules (a programming error)."""
