"""``zdrone view``: a local web page that shows the fleet live: who commands which drone, every link.

Theory of operation
-------------------
**Reading.** The view is the fleet's viewer node (role ``viewer``, from its bundle): a Zenoh client
whose router ACL lets it subscribe ``zdrone-ops/*`` and nothing else (no put, no query, no key that
commands). Each GS seals its operations picture for it (``zdrone.core.opspicture``); a part that does
not open, replays, or is an old start of a GS is dropped and counted (shown on the page). One thread
(``Follower``) drains the inbox and merges the parts into a ``FleetPicture`` under a lock, which checks
each drone's signed word on who commands it against the drone's signing keys over time.

**Serving.** Starlette on uvicorn: ``/`` the page, ``/static/*`` its own JS and CSS (shipped in the
package, no CDN, no map tiles: the plan is drawn from the fleet's own geometry), ``/api/stream`` the
picture as server-sent events (msgspec JSON: ``init`` with the geometry and every track so far, then
``picture`` at most every ``PUSH_MIN_S`` when something changed and at least every ``PUSH_MAX_S``, so
staleness shows without news), ``/report`` the run's HTML report when ``--run`` names a folder that has
one. The page reconnects by itself (the stream's ``retry``) when the server restarts, and shows every
drone as stale while it has no stream.

**Exposure.** Loopback by default. Any other address needs ``--listen`` *and* ``--token``: every request
then carries the token (``?token=`` once, kept in an HttpOnly, SameSite=Strict cookie, or an
``Authorization: Bearer`` header), compared in constant time. The ``Host`` header must name the
address served (a DNS-rebinding page cannot read it), and every response forbids outside sources
(``Content-Security-Policy: default-src 'self'``), framing and referrers.
"""

from __future__ import annotations

import asyncio
import hmac
import ipaddress
import logging
import threading
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import msgspec

from ..core.errors import ConfigError, UsageError
from ..core.opspicture import OPS_MAX_BYTES, FleetPicture, OpsOpener, OpsReport
from ..fleet import keyexprs as kx
from ..net.shutdown import serve_signals

log = logging.getLogger(__name__)

#: The stream sends a picture at most this often when something changed ...
PUSH_MIN_S = 0.1
#: ... and at least this often (ages move on, staleness shows).
PUSH_MAX_S = 0.5
#: What the page waits before reconnecting a lost stream (ms).
RETRY_MS = 500
STATIC = ("index.html", "view.js", "view.css")
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; "
                               "connect-src 'self'; frame-ancestors 'none'; base-uri 'none'; form-action 'none'",
    "X-Content-Type-Options": "nosniff", "Referrer-Policy": "no-referrer", "X-Frame-Options": "DENY",
    "Cache-Control": "no-store"}
COOKIE = "zdrone_view"


@dataclass(frozen=True, slots=True)
class ViewOptions:
    fleet: str
    router: str
    port: int = 8470
    listen: str | None = None  # None: 127.0.0.1
    token: str | None = None
    run: str | None = None  # a run's folder: its report.html is linked
    viewer: str | None = None  # the viewer's name (default: the fleet's viewer whose secret is in the bundle)


def check_exposure(listen: str | None, token: str | None) -> str:
    """The address to bind: loopback unless ``--listen`` names another *and* a token is given."""
    host = listen or "127.0.0.1"
    try:
        addr = ipaddress.ip_address(host)
    except ValueError:
        raise UsageError(f"--listen {host}: an IP address (e.g. 127.0.0.1)") from None
    if not addr.is_loopback and not token:
        raise UsageError(f"--listen {host}: not loopback; remote access needs --token (a long random secret)")
    if token is not None and len(token) < 16:
        raise UsageError("--token: at least 16 characters")
    return host


def _geometry(fleet: Any) -> dict[str, Any]:
    home = fleet.home
    stations = [{"name": g, "lat": n.coverage.lat, "lon": n.coverage.lon, "radius_m": n.coverage.radius_m}
                for g, n in sorted(fleet.nodes.items()) if n.role == "gs" and n.coverage is not None]
    return {"home": None if home is None else {"lat": home.lat, "lon": home.lon}, "stations": stations}


class Follower:
    """The viewer's Zenoh side: the parts the GSs publish, opened and merged (one thread)."""

    def __init__(self, opts: ViewOptions) -> None:
        from ..net.runtime import NodeRuntime
        from ..fleet.files import fleet_path, load_fleet

        fleet = load_fleet(opts.fleet)
        names = [opts.viewer] if opts.viewer else [
            v for v in fleet.viewers() if (fleet_path(opts.fleet).parent / "secrets" / f"{v}.json").exists()]
        if not names:
            raise ConfigError(f"{opts.fleet}: no viewer's secret here (export the viewer's bundle: zdrone fleet export V)")
        self.rt = NodeRuntime(opts.fleet, names[0], "viewer", opts.router, None)
        self.fleet = self.rt.fleet
        self.opener = OpsOpener(self.rt.secret.identity, names[0],
                                {g: self.fleet.nodes[g].public_bytes for g in self.fleet.ground_stations()
                                 if not self.fleet.is_revoked(g)})
        from ..fleet.revisions import signing_key_history

        # each drone's signing keys over time: its attestations of who commands it are checked against them
        history = signing_key_history(opts.fleet)
        self.picture = FleetPicture({d: history[d] for d in self.fleet.drones() if d in history})
        self.lock = threading.Lock()
        self.stopping = threading.Event()  # the server is ending: the streams end (the page reconnects)
        self.rt.subscribe(kx.ops_all(), "ops", kx.gs_of, limit=OPS_MAX_BYTES)
        self._thread = threading.Thread(target=self._run, name="follower", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        while self.rt.running:
            try:
                self.rt.poll_paths()
                self.rt.inbox.drain(0.1, self._on_part)
            except Exception:  # last resort: the view goes on (counted, logged with its stack)
                log.exception("follower")
                self.opener.drops["internal_error"] += 1

    def _on_part(self, kind: str, gs: str, data: Any, now: float) -> None:
        with self.lock:
            got = self.opener.open(gs, kx.ops(gs), bytes(data), time.monotonic(), time.time())
            if isinstance(got, OpsReport):
                self.picture.on_report(got, time.monotonic())

    def snapshot(self) -> dict[str, Any]:
        with self.lock:
            snap = self.picture.snapshot(time.monotonic())
            snap["drops"] = dict(self.opener.drops) | {k: v for k, v in self.rt.inbox.stats().items() if v}
            snap["opened"] = self.opener.opened
            return snap

    def tracks(self) -> dict[str, Any]:
        with self.lock:
            return self.picture.track_points()

    @property
    def version(self) -> int:
        return self.picture.version

    def close(self) -> None:
        self.rt.stop()
        self._thread.join(2.0)
        from ..core import records as rec

        self.rt.close({}, rec.Closed)


def build_app(follower: Any, opts: ViewOptions, host: str) -> Any:
    """The Starlette application (``follower``: ``snapshot()``, ``tracks()``, ``version``, ``fleet``)."""
    from starlette.applications import Starlette
    from starlette.requests import Request
    from starlette.responses import PlainTextResponse, Response, StreamingResponse
    from starlette.routing import Route

    enc = msgspec.json.Encoder()
    files = {name: (resources.files("zdrone.view") / "static" / name).read_bytes() for name in STATIC}
    types = {"html": "text/html; charset=utf-8", "js": "text/javascript; charset=utf-8", "css": "text/css; charset=utf-8"}
    allowed_hosts = {f"{host}:{opts.port}", f"[{host}]:{opts.port}"} | (
        {f"localhost:{opts.port}"} if ipaddress.ip_address(host).is_loopback else set())
    geometry = _geometry(follower.fleet)
    run = Path(opts.run) if opts.run else None

    def refused(request: Request) -> Response | None:
        if request.headers.get("host", "") not in allowed_hosts:
            return PlainTextResponse("unknown host", status_code=421, headers=SECURITY_HEADERS)
        if opts.token is None:
            return None
        given = request.query_params.get("token") or request.cookies.get(COOKIE) or \
            request.headers.get("authorization", "").removeprefix("Bearer ")
        if not hmac.compare_digest(given.encode(), opts.token.encode()):
            return PlainTextResponse("token required", status_code=401, headers=SECURITY_HEADERS)
        return None

    def static(name: str, request: Request) -> Response:
        bad = refused(request)
        if bad is not None:
            return bad
        resp = Response(files[name], media_type=types[name.rsplit(".", 1)[1]], headers=SECURITY_HEADERS)
        if opts.token is not None and request.query_params.get("token"):
            resp.set_cookie(COOKIE, opts.token, httponly=True, samesite="strict", secure=False)
        return resp

    async def page(request: Request) -> Response:
        return static("index.html", request)

    async def asset(request: Request) -> Response:
        name = request.path_params["name"]
        if name not in files or name == "index.html":
            return PlainTextResponse("not found", status_code=404, headers=SECURITY_HEADERS)
        return static(name, request)

    async def report(request: Request) -> Response:
        bad = refused(request)
        if bad is not None:
            return bad
        path = run / "report.html" if run is not None else None
        if path is None or not path.is_file():
            return PlainTextResponse("no report (yet)", status_code=404, headers=SECURITY_HEADERS)
        return Response(path.read_bytes(), media_type=types["html"],
                        headers={**SECURITY_HEADERS, "Content-Security-Policy": "default-src 'self' 'unsafe-inline' data:"})

    def has_report() -> bool:
        return run is not None and (run / "report.html").is_file()

    async def stream(request: Request) -> Response:
        bad = refused(request)
        if bad is not None:
            return bad

        async def events() -> Any:
            init = {"geometry": geometry, "tracks": follower.tracks()}
            yield b"retry: %d\nevent: init\ndata: " % RETRY_MS + enc.encode(init) + b"\n\n"
            seen, sent = -1, 0.0
            while not follower.stopping.is_set() and not await request.is_disconnected():
                now = time.monotonic()
                version = follower.version
                if (version != seen and now - sent >= PUSH_MIN_S) or now - sent >= PUSH_MAX_S:
                    snap = follower.snapshot()
                    snap["report"] = has_report()
                    snap["server_time"] = time.time()
                    yield b"event: picture\ndata: " + enc.encode(snap) + b"\n\n"
                    seen, sent = version, now
                await asyncio.sleep(0.02)

        return StreamingResponse(events(), media_type="text/event-stream", headers={**SECURITY_HEADERS, "X-Accel-Buffering": "no"})

    return Starlette(routes=[Route("/", page), Route("/static/{name}", asset), Route("/api/stream", stream),
                             Route("/report", report)])


def run_view(opts: ViewOptions) -> int:
    import uvicorn

    host = check_exposure(opts.listen, opts.token)
    follower = Follower(opts)
    follower.start()
    config = uvicorn.Config(build_app(follower, opts, host), host=host, port=opts.port, log_level="warning",
                            lifespan="off", access_log=False, timeout_graceful_shutdown=1)
    server = uvicorn.Server(config)

    def announce() -> None:
        while not server.started and not server.should_exit:
            time.sleep(0.02)
        if server.started:
            shown = f"[{host}]" if ":" in host else host
            print(f"zdrone view: http://{shown}:{opts.port}/ (viewer {follower.rt.name}, router {opts.router})", flush=True)

    threading.Thread(target=announce, name="announce", daemon=True).start()
    # SIGTERM/SIGINT are blocked in every thread (``zdrone.net.shutdown``, as for the other nodes): the
    # signal thread asks uvicorn to end (it closes the streams within a second), then the session closes
    closed = threading.Event()

    def stop() -> None:
        follower.stopping.set()
        server.should_exit = True

    serve_signals(stop, follower.rt.close_sessions, closed)
    try:
        server.run()
    finally:
        follower.close()
        closed.set()
    if not server.started:
        print(f"zdrone view: could not serve on {host}:{opts.port}", flush=True)
        return 2
    return 0


def view_command(args: Any) -> int:
    if not 1 <= args.port <= 65535:
        raise UsageError(f"--port {args.port}: must be 1..65535")
    return run_view(ViewOptions(fleet=args.fleet, router=args.router, port=args.port, listen=args.listen,
                                token=args.token, run=args.run, viewer=args.id))


def add_view(sub: Any, func: Any) -> None:
    """``zdrone view``'s parser."""
    p = sub.add_parser("view", help="live web view of the fleet: who commands which drone, every link (read-only)")
    p.add_argument("--fleet", default="fleet", help="the viewer's bundle (or a fleet directory holding its secret)")
    p.add_argument("--router", default="tcp/127.0.0.1:7447", help="Zenoh router endpoint")
    p.add_argument("--id", default=None, help="the viewer's name in the fleet (default: the one whose secret is here)")
    p.add_argument("--port", type=int, default=8470, help="HTTP port (default 8470)")
    p.add_argument("--listen", default=None, metavar="ADDR",
                   help="address to serve on (default 127.0.0.1); any other needs --token")
    p.add_argument("--token", default=None, help="a secret every request must carry (?token= once, then a cookie)")
    p.add_argument("--run", default=None, metavar="DIR", help="a run folder: its report.html is linked from the page")
    p.set_defaults(func=func)
