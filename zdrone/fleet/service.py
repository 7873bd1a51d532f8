"""``zdrone service NODE --bundle DIR``: a hardened systemd unit for one host's node, from its bundle.

The unit runs the node as the static system user ``zdrone`` (which owns the bundle, mode 0700),
restarts it on failure, sends its log lines to the journal (plain: the journal stamps them), keeps
its state and event logs in systemd's own directories (``StateDirectory=``, ``LogsDirectory=``:
``/var/lib/zdrone-<node>``, ``/var/log/zdrone-<node>``), and takes away everything a node does not
use: no privileges or capabilities, a read-only system, no home directories, private /tmp, no
kernel tunables, modules, logs or clock, a system call allow-list, network families limited to IP,
netlink and Unix sockets, and devices closed except the drone's serial port to the flight
controller (``--vehicle /dev/ttyACM0,921600``), which it reaches through the ``dialout`` group.
``systemd-analyze security --offline=yes`` rates every kind of node's unit at an exposure <= 2.0.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass
from pathlib import Path

from zdrone.core.errors import ConfigError
from zdrone.fleet.bundle import BUNDLE_FILE, check_bundle

SERVICE_USER = "zdrone"

_HARDENING = """\
NoNewPrivileges=yes
CapabilityBoundingSet=
AmbientCapabilities=
ProtectSystem=strict
ProtectHome=yes
PrivateTmp=yes
ProtectKernelTunables=yes
ProtectKernelModules=yes
ProtectKernelLogs=yes
ProtectControlGroups=yes
ProtectClock=yes
ProtectHostname=yes
ProtectProc=invisible
ProcSubset=pid
RestrictNamespaces=yes
RestrictRealtime=yes
RestrictSUIDSGID=yes
LockPersonality=yes
MemoryDenyWriteExecute=yes
RemoveIPC=yes
KeyringMode=private
PrivateMounts=yes
UMask=0077
SystemCallArchitectures=native
SystemCallFilter=@system-service
SystemCallFilter=~@privileged @resources @mount @swap @reboot @raw-io @module @obsolete @debug @cpu-emulation
SystemCallErrorNumber=EPERM
RestrictAddressFamilies=AF_INET AF_INET6 AF_NETLINK AF_UNIX
"""


@dataclass(frozen=True)
class ServiceSpec:
    """What the unit is for: the node, its bundle folder on the host, its command line."""

    node: str
    role: str
    bundle: Path
    argv: tuple[str, ...]
    device: str | None  # the serial device the drone reaches its flight controller through
    peers: tuple[str, ...] | None = None  # the only addresses it may talk to (None: any; a router's clients)


def serial_device(vehicle: str | None) -> str | None:
    """The device path of a serial vehicle connection (``/dev/ttyACM0,921600``), else None."""
    if vehicle and vehicle.startswith("/dev/"):
        return vehicle.split(",", 1)[0]
    return None


def service_spec(node: str, bundle: str | Path, exe: str, router: str | None = None,
                 vehicle: str | None = None, events_max_mb: float = 64.0, extra: tuple[str, ...] = ()) -> ServiceSpec:
    """The unit's content for ``node`` from its bundle (checked: its own secrets only); ``extra``:
    further options of the node command (a GS's ``--pair``, ``--gcs udpin:0.0.0.0:14550`` ...)."""
    d = Path(bundle).resolve()
    if not (d / BUNDLE_FILE).is_file():
        raise ConfigError(f"{d}: not a bundle (make one with: zdrone fleet export {node} --out {d})")
    b = check_bundle(d)
    if b.node != node:
        raise ConfigError(f"{d}: the bundle of {b.node}, not of {node}")
    if vehicle is not None and b.role != "drone":
        raise ConfigError(f"--vehicle: only a drone has a vehicle ({node} is a {b.role})")
    logs = f"%L/zdrone-{node}"
    if b.role == "router":
        cfg = "router" if node == "router" else node
        argv: tuple[str, ...] = (exe, "-v", "router", "-c", str(d / "router" / f"{cfg}.json5"))
        if router:
            argv += ("--listen", router)
        return ServiceSpec(node, b.role, d, argv + extra, None)
    endpoint = router or ("tls/127.0.0.1:7447" if b.tls else "tcp/127.0.0.1:7447")
    common = ("--id", node, "--fleet", str(d), "--router", endpoint, "--events", f"{logs}/events.jsonl",
              "--events-max-mb", f"{events_max_mb:g}")
    if b.role == "drone":
        argv = (exe, "-v", "drone", *common, "--vehicle", vehicle or "udpout:127.0.0.1:14580", *extra)
        return ServiceSpec(node, b.role, d, argv, serial_device(vehicle), _peers(endpoint, vehicle))
    gcs = [extra[i + 1] for i, a in enumerate(extra[:-1]) if a == "--gcs"]  # applications reach the GS there
    return ServiceSpec(node, b.role, d, (exe, "-v", "gs", *common, *extra), None, _peers(endpoint, *gcs))


def _peers(*endpoints: str | None) -> tuple[str, ...] | None:
    """The IP allow-list of a node: loopback and the address of each endpoint it reaches; None (no
    list) when one names a host rather than an address, or listens for peers beyond loopback
    (``udpin:``/``tcpin:``: a vehicle or GCS applications, from addresses not known here)."""
    import ipaddress

    out = ["localhost"]
    for ep in endpoints:
        if not ep or ep.startswith("/dev/"):
            continue
        listening = ep.startswith(("udpin:", "tcpin:"))
        rest = ep.split(":", 1)[1] if ep.startswith(("udpin:", "udpout:", "tcpin:", "tcp:")) else ep.split("/", 1)[-1]
        host = rest.rsplit(":", 1)[0].strip("[]")
        try:
            ip = ipaddress.ip_address(host)
        except ValueError:
            return None
        if ip.is_loopback:
            continue
        if listening:
            return None
        out.append(str(ip))
    return tuple(dict.fromkeys(out))


def render_unit(spec: ServiceSpec) -> str:
    """The systemd unit text."""
    what = {"router": "Zenoh router (fleet auth and access control)",
            "drone": "drone companion (vehicle link, security module, hand-over authority)",
            "gs": "ground station"}[spec.role]
    unit = [f"# zdrone {spec.node}: written by 'zdrone service {spec.node} --bundle {spec.bundle}'.",
            f"# The bundle must belong to the user {SERVICE_USER} (chown -R {SERVICE_USER}: {spec.bundle}; "
            f"chmod 700 {spec.bundle}).",
            "[Unit]",
            f"Description=zdrone {spec.node}: {what}",
            "Wants=network-online.target time-sync.target",
            "After=network-online.target time-sync.target"]
    if spec.device:
        dev_unit = spec.device.removeprefix("/").replace("-", "\\x2d").replace("/", "-") + ".device"
        unit += [f"Wants={dev_unit}", f"After={dev_unit}"]
    unit += ["StartLimitIntervalSec=60", "StartLimitBurst=10", "",
             "[Service]",
             "Type=exec",
             "ExecStart=" + " ".join(_quote(a) for a in spec.argv),
             "Restart=on-failure",
             "RestartSec=1",
             "TimeoutStopSec=15",
             f"User={SERVICE_USER}",
             f"Group={SERVICE_USER}",
             f"StateDirectory=zdrone-{spec.node}",
             f"LogsDirectory=zdrone-{spec.node}",
             "StateDirectoryMode=0700",
             "LogsDirectoryMode=0700",
             f"WorkingDirectory=%S/zdrone-{spec.node}",
             f"Environment=ZDRONE_STATE_DIR=%S/zdrone-{spec.node}",
             "Environment=PYTHONUNBUFFERED=1",
             "StandardOutput=journal",
             "StandardError=journal",
             f"SyslogIdentifier=zdrone-{spec.node}",
             f"ReadOnlyPaths={_quote(str(spec.bundle))}",
             _HARDENING.rstrip("\n")]
    if spec.peers is not None:  # a node talks to its router (and vehicle) only
        unit += ["IPAddressDeny=any", "IPAddressAllow=" + " ".join(spec.peers)]
    if spec.device:  # the flight controller's serial port, and nothing else of /dev
        unit += ["PrivateDevices=no", "DevicePolicy=closed", f"DeviceAllow={spec.device} rw", "SupplementaryGroups=dialout"]
    else:
        unit += ["PrivateDevices=yes", "PrivateUsers=yes"]
    unit += ["", "[Install]", "WantedBy=multi-user.target", ""]
    return "\n".join(unit)


def _quote(arg: str) -> str:
    """An ExecStart argument: quoted when it must be; ``%`` specifiers kept for the ones we write."""
    return shlex.quote(arg) if any(c in arg for c in " \t\"'\\;") else arg

