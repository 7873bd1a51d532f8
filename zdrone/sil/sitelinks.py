"""TESTBED: a run's sites (``--sites``, and the scenarios that need two): a router per site, meshed over a
backhaul link per pair of sites; the drone reaches each site through that site's radio link, up only
while the vehicle is inside the site's coverage (from the simulator's true position, ``SiteCoverage``).
On loopback the links are relays the testbed opens and closes; with ``--netns`` each site and the drone
have their own network namespace and the links are veth pairs. A fault cuts or mends a link
(``link_fault``).
"""

from __future__ import annotations

import socket
import time
from pathlib import Path
from typing import Any

from zdrone.fleet.files import init_fleet, load_sites
from zdrone.fleet.routerconfig import mesh_endpoint
from zdrone.net.eventlog import EventLog
from zdrone.sil.netns import NetnsTopology
from zdrone.sil.ports import free_port
from zdrone.sil.radiolink import DatagramLink, RadioLink, SiteCoverage, SwitchedLink, TruthReceiver, site_circles
from zdrone.sil.testbed_records import LinkFault, RadioLinkChanged


class SiteLinks:
    """``Demo``'s sites and links. A mixin: the run's ``Demo`` holds the state (its dataclass fields
    named here) and starts the routers (``start``, ``wait_line``, the fleet's bundles)."""

    opts: Any  # the run's ``DemoOptions``
    out: Path
    notes: list[str]
    router: str
    sites: dict[str, dict[str, Any]]  # site -> endpoint, GSs
    links: dict[str, SwitchedLink]  # radio per site, backhaul per pair
    coverage: SiteCoverage | None
    truth: TruthReceiver | None
    radio_log: EventLog | None
    site_of_endpoint: dict[str, str]  # the drone's path endpoint -> site
    netns: NetnsTopology | None

    def _start_sites(self, rport: int) -> None:
        """A router per site, meshed through a backhaul link per pair of sites; the drone reaches each
        site through that site's radio link, up only while the vehicle is inside the site's coverage
        (from the simulator's true position). No frame filter: coverage is which links exist.
        On loopback the links are relays the testbed opens and closes; with ``--netns`` each site and
        the drone have their own network namespace and the links are veth pairs."""
        if self.opts.netns:
            self._start_sites_netns()
            return
        site_eps = [f"tls/127.0.0.1:{rport}", f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]
        self.router = site_eps[0]
        fleet = init_fleet(self.out / "fleet", sites=site_eps, nodes_spec=self._nodes_spec(), **self._lease())
        self.sites = load_sites(self.out / "fleet")
        self._export_bundles(list(self.sites))
        names = list(self.sites)
        ports = {site: int(self.sites[site]["endpoint"].rsplit(":", 1)[1]) for site in names}
        for n, site in enumerate(names):
            connect: list[str] = []
            for earlier in names[:n]:  # site N reaches sites < N over its backhaul link to each
                link = DatagramLink(f"backhaul-{earlier}-{site}", ("127.0.0.1", ports[earlier]), up=True)
                self.links[link.name] = link
                connect += ["--connect", mesh_endpoint(f"tls/{link.endpoint}")]  # the mesh runs over QUIC
            name = "router" if n == 0 else f"router{n + 1}"
            r = self.start(name, self._z() + ["router", "-c", f"bundles/{site}/router/{site}.json5", *connect])
            self.wait_line(r, "listening", 20)
        radios = {site: RadioLink(site, ("127.0.0.1", ports[site]), up=self.opts.vehicle is not None) for site in names}
        self.links.update(radios)
        self.site_of_endpoint = {f"tls/{link.endpoint}": site for site, link in radios.items()}
        self._start_coverage(fleet, radios, "127.0.0.1")

    def _start_sites_netns(self) -> None:
        """Each site and the drone in their own namespace: the site's router listens on 127.0.0.1
        (its GSs) and on its radio address (the drone, and the higher sites over the backhaul)."""
        names = ["site-1", "site-2"]
        topo = self.netns = NetnsTopology(names)
        topo.create()
        port = 7447  # each router alone in its namespace
        fleet = init_fleet(self.out / "fleet", sites=[f"tls/{topo.radio_ip[site]}:{port}" for site in names],
                           nodes_spec=self._nodes_spec(), **self._lease())
        self.sites = load_sites(self.out / "fleet")
        self._export_bundles(list(self.sites))
        self.router = f"tls/127.0.0.1:{port}"  # inside site 1's namespace (the attackers run there)
        for n, site in enumerate(names):
            name = "router" if n == 0 else f"router{n + 1}"
            r = self.start(name, self._z() + ["router", "-c", f"bundles/{site}/router/{site}.json5", "--listen",
                                              f"tls/127.0.0.1:{port}", "--listen", f"tls/{topo.radio_ip[site]}:{port}",
                                              "--listen", mesh_endpoint(f"tls/{topo.radio_ip[site]}:{port}")],
                           ns=topo.site_ns[site])
            self.wait_line(r, "listening", 20)
        self.links.update(topo.backhauls)
        self.links.update(topo.radios)
        self.site_of_endpoint = {f"tls/{topo.radio_ip[site]}:{port}": site for site in names}
        if self.opts.vehicle is not None:
            raise RuntimeError("--netns runs the built-in simulator in the drone's namespace: no --vehicle")
        self._start_coverage(fleet, dict(topo.radios), topo.control_host)

    def _start_coverage(self, fleet: Any, radios: dict[str, SwitchedLink], truth_host: str) -> None:
        self.radio_log = EventLog(self.out / "radio.jsonl", "radio")
        if self.opts.vehicle is None:  # the built-in simulator tells where the vehicle truly is
            log_ = self.radio_log
            self.coverage = SiteCoverage(site_circles(fleet, self.sites), radios,
                                         lambda site, up, p: log_.write_record(RadioLinkChanged(
                                             site=site, up=up, position=(round(p.lat, 7), round(p.lon, 7), round(p.alt, 2)))))
            self.truth = TruthReceiver(self.coverage.update, truth_host)
        else:
            self.notes.append("--vehicle with --sites: no true position, every site's radio stays up")

    def _ns(self, gs: str | None = None) -> str | None:
        """With --netns: the drone's namespace, or GS ``gs``'s site's."""
        if self.netns is None:
            return None
        if gs is None:
            return self.netns.drone_ns
        return next(self.netns.site_ns[site] for site, info in self.sites.items() if gs in info["ground_stations"])

    def _truth_args(self) -> list[str]:
        return ["--truth", f"{self.truth.host}:{self.truth.port}"] if self.truth is not None else []

    def _wait_coverage(self, timeout: float = 20.0) -> None:
        """With radio links: the first true position has set them (the drone starts in range)."""
        deadline = time.monotonic() + timeout
        while self.coverage is not None and self.coverage.updates == 0:
            if time.monotonic() > deadline:
                raise RuntimeError("no true position from the simulator: radio links cannot be set")
            time.sleep(0.05)

    def link_fault(self, target: str, up: bool) -> None:
        """Cut or mend a testbed link (``backhaul``: every backhaul link; a site's name: its radio, held
        down whatever the vehicle's position until mended, when the position decides again)."""
        for name, link in self.links.items():
            if name == target or (target == "backhaul" and name.startswith("backhaul-")):
                if self.coverage is not None and name in self.coverage.links:
                    self.coverage.jam(name, not up)
                else:
                    link.set_up(up)
                if self.radio_log is not None:
                    self.radio_log.write_record(LinkFault(link=name, up=up))

    def close_links(self) -> None:
        if self.truth is not None:
            self.truth.close()
            self.truth = None
        for link in self.links.values():
            link.close()
        self.links.clear()
        if self.netns is not None:
            self.netns.destroy()
            self.netns = None
        if self.radio_log is not None:
            self.radio_log.close()
