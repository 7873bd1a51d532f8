"""TESTBED ONLY: sites and the drone in their own network namespaces (``zdrone demo --sites --netns``).

Theory of operation
-------------------
Root only. ``NetnsTopology.create`` makes one namespace per site and one for the drone (with its
simulator), and joins them with veth pairs:

* a **radio** per site, ``drone <-> site-N`` (10.232.T.4N/30: the site's router at .4N+1, the drone
  at .4N+2): the testbed takes it down and up from the vehicle's position (``VethLink``), so a site
  out of range is a link without carrier, exactly as a radio out of range: nothing is closed, the
  frames just stop, and each side's Zenoh lease notices;
* a **backhaul** per pair of sites (10.233.T.0/30 for sites 1-2, and so on), with a route in the
  higher site to the lower site's radio subnet, so that the lower site's router (whose certificate
  names its radio address) is reached over the backhaul and never over the drone's radio;
* a **control** pair between the host and the drone's namespace (10.234.T.0/30), which carries only
  the simulator's true position to the testbed (never Zenoh).

Each site's GSs live in the site's namespace and reach its router on 127.0.0.1. Only addresses
inside these namespaces are used; ``destroy`` removes them all (deleting a namespace deletes its
veths).
"""

from __future__ import annotations

import logging
import os
import random
import shutil
import subprocess
import threading

log = logging.getLogger(__name__)


class NetnsError(RuntimeError):
    """The namespaces could not be made (not root, no iproute2, or the kernel refused)."""


def _ip(*args: str, ns: str | None = None) -> None:
    cmd = ["ip"] + (["-n", ns] if ns else []) + list(args)
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=10)
    if out.returncode != 0:
        raise NetnsError(f"{' '.join(cmd)}: {out.stderr.strip() or out.returncode}")


def netns_refusal() -> str | None:
    """Why network namespaces cannot be made here (None: they can)."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    if shutil.which("ip") is None:
        return "network namespaces need iproute2 (ip)"
    return None


class VethLink:
    """One veth pair, brought down and up from one end (the other end loses its carrier); a
    ``radiolink.SwitchedLink``."""

    def __init__(self, name: str, ns: str, ifname: str, up: bool = True, routes: tuple[tuple[str, str, str], ...] = ()) -> None:
        self.name, self.ns, self.ifname = name, ns, ifname
        self.routes = routes  # (namespace, subnet, via): put back each time the link comes up
        self._up = up
        self._lock = threading.Lock()

    @property
    def up(self) -> bool:
        return self._up

    def set_up(self, up: bool) -> bool:
        with self._lock:
            if up == self._up:
                return False
            self._up = up
            try:
                _ip("link", "set", "dev", self.ifname, "up" if up else "down", ns=self.ns)
                if up:
                    for ns, subnet, via in self.routes:
                        _ip("route", "replace", subnet, "via", via, ns=ns)
            except NetnsError as exc:
                log.error("%s: %s", self.name, exc)
            return True

    def close(self) -> None:
        """Nothing to do: the namespaces' removal removes the pair."""


class NetnsTopology:
    """The namespaces, addresses and links of one demo run."""

    def __init__(self, sites: list[str]) -> None:
        self.tag = f"{os.getpid() % 1000:03d}{random.randint(0, 99):02d}"
        self.octet = random.randint(1, 250)
        self.sites = list(sites)
        self.site_ns = {site: f"zd{self.tag}s{n + 1}" for n, site in enumerate(self.sites)}
        self.drone_ns = f"zd{self.tag}d"
        self.radio_ip = {site: f"10.232.{self.octet}.{4 * (n + 1) + 1}" for n, site in enumerate(self.sites)}
        self.control_host = f"10.234.{self.octet}.1"
        self.radios: dict[str, VethLink] = {}
        self.backhauls: dict[str, VethLink] = {}
        self._made: list[str] = []

    def exec_prefix(self, ns: str) -> list[str]:
        return ["ip", "netns", "exec", ns]

    def create(self) -> None:
        refusal = netns_refusal()
        if refusal:
            raise NetnsError(refusal)
        try:
            self._create()
        except NetnsError:
            self.destroy()
            raise

    def _create(self) -> None:
        t, o = self.tag, self.octet
        for ns in [*self.site_ns.values(), self.drone_ns]:
            _ip("netns", "add", ns)
            self._made.append(ns)
            _ip("link", "set", "lo", "up", ns=ns)
        for n, site in enumerate(self.sites):  # a radio per site
            s_if, d_if, ns = f"zd{t}r{n + 1}s", f"zd{t}r{n + 1}d", self.site_ns[site]
            base = 4 * (n + 1)
            _ip("link", "add", s_if, "netns", ns, "type", "veth", "peer", "name", d_if, "netns", self.drone_ns)
            _ip("addr", "add", f"10.232.{o}.{base + 1}/30", "dev", s_if, ns=ns)
            _ip("addr", "add", f"10.232.{o}.{base + 2}/30", "dev", d_if, ns=self.drone_ns)
            _ip("link", "set", s_if, "up", ns=ns)
            _ip("link", "set", d_if, "down", ns=self.drone_ns)  # out of range until the vehicle's position says
            self.radios[site] = VethLink(site, self.drone_ns, d_if, up=False)
        pair = 0
        for hi in range(len(self.sites)):  # a backhaul per pair of sites; the higher one routes to the lower
            for lo in range(hi):
                lo_site, hi_site = self.sites[lo], self.sites[hi]
                a_if, b_if = f"zd{t}b{pair}l", f"zd{t}b{pair}h"
                _ip("link", "add", a_if, "netns", self.site_ns[lo_site], "type", "veth", "peer", "name", b_if,
                    "netns", self.site_ns[hi_site])
                _ip("addr", "add", f"10.233.{o}.{4 * pair + 1}/30", "dev", a_if, ns=self.site_ns[lo_site])
                _ip("addr", "add", f"10.233.{o}.{4 * pair + 2}/30", "dev", b_if, ns=self.site_ns[hi_site])
                _ip("link", "set", a_if, "up", ns=self.site_ns[lo_site])
                _ip("link", "set", b_if, "up", ns=self.site_ns[hi_site])
                route = (self.site_ns[hi_site], f"10.232.{o}.{4 * (lo + 1)}/30", f"10.233.{o}.{4 * pair + 1}")
                _ip("route", "replace", route[1], "via", route[2], ns=route[0])
                name = f"backhaul-{lo_site}-{hi_site}"
                self.backhauls[name] = VethLink(name, self.site_ns[hi_site], b_if, up=True, routes=(route,))
                pair += 1
        h_if, d_if = f"zd{t}c0h", f"zd{t}c0d"  # control: the simulator's true position to the testbed
        _ip("link", "add", h_if, "type", "veth", "peer", "name", d_if, "netns", self.drone_ns)
        self._made.append(f"link:{h_if}")
        _ip("addr", "add", f"{self.control_host}/30", "dev", h_if)
        _ip("addr", "add", f"10.234.{o}.2/30", "dev", d_if, ns=self.drone_ns)
        _ip("link", "set", h_if, "up")
        _ip("link", "set", d_if, "up", ns=self.drone_ns)
        log.info("network namespaces %s and %s made", ", ".join(self.site_ns.values()), self.drone_ns)

    def destroy(self) -> None:
        """Remove every namespace and host-side veth this topology made (each on its own)."""
        for made in reversed(self._made):
            if made.startswith("link:"):
                subprocess.run(["ip", "link", "del", made[5:]], capture_output=True, timeout=10)
            else:
                subprocess.run(["ip", "netns", "del", made], capture_output=True, timeout=10)
        self._made.clear()


class ShapedRadio:
    """The drone alone in a network namespace behind one radio: a veth pair from the host
    (``host_ip``) to the drone's namespace (``drone_ip``), shaped to ``rate_kbit`` each way by a
    token bucket (``tc tbf``) with a queue of ``queue_ms`` at that rate, as a slow radio is. Root
    only; ``destroy`` removes the namespace and the pair."""

    def __init__(self, rate_kbit: int = 4000, queue_ms: int = 200) -> None:
        self.rate_kbit, self.queue_ms = rate_kbit, queue_ms
        self.tag = f"{os.getpid() % 1000:03d}{random.randint(0, 99):02d}"
        octet = random.randint(1, 250)
        self.ns = f"zd{self.tag}r"
        self.host_if, self.drone_if = f"zd{self.tag}rh", f"zd{self.tag}rd"
        self.host_ip, self.drone_ip = f"10.235.{octet}.1", f"10.235.{octet}.2"
        self._made: list[str] = []

    def exec_prefix(self, ns: str) -> list[str]:
        """How to run a command in namespace ``ns`` (this radio's only: the topology's interface)."""
        if ns != self.ns:
            raise ValueError(f"{ns}: not this radio's namespace {self.ns}")
        return ["ip", "netns", "exec", ns]

    def create(self) -> None:
        refusal = netns_refusal() or (None if shutil.which("tc") else "a shaped radio needs iproute2 (tc)")
        if refusal:
            raise NetnsError(refusal)
        try:
            _ip("netns", "add", self.ns)
            self._made.append(self.ns)
            _ip("link", "set", "lo", "up", ns=self.ns)
            _ip("link", "add", self.host_if, "type", "veth", "peer", "name", self.drone_if, "netns", self.ns)
            self._made.append(f"link:{self.host_if}")
            _ip("addr", "add", f"{self.host_ip}/30", "dev", self.host_if)
            _ip("addr", "add", f"{self.drone_ip}/30", "dev", self.drone_if, ns=self.ns)
            _ip("link", "set", self.host_if, "up")
            _ip("link", "set", self.drone_if, "up", ns=self.ns)
            for dev, ns in ((self.host_if, None), (self.drone_if, self.ns)):
                self._shape(dev, ns)
        except NetnsError:
            self.destroy()
            raise

    def _shape(self, dev: str, ns: str | None) -> None:
        burst = max(1600, self.rate_kbit * 1000 // 8 // 100)  # 10 ms at the rate
        cmd = [*(["ip", "netns", "exec", ns] if ns else []), "tc", "qdisc", "replace", "dev", dev, "root", "tbf",
               "rate", f"{self.rate_kbit}kbit", "burst", str(burst), "latency", f"{self.queue_ms}ms"]
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=10)
        if out.returncode != 0:
            raise NetnsError(f"{' '.join(cmd)}: {out.stderr.strip() or out.returncode}")

    def destroy(self) -> None:
        for made in reversed(self._made):
            if made.startswith("link:"):
                subprocess.run(["ip", "link", "del", made[5:]], capture_output=True, timeout=10)
            else:
                subprocess.run(["ip", "netns", "del", made], capture_output=True, timeout=10)
        self._made.clear()
