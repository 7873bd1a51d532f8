"""``zdrone view``: a local web page that shows the fleet live: who commands which drone, every link.

Theory of operation
-------------------
**Reading.** The view is the fleet's viewer node (role ``viewer``, from its bundle): a Zenoh client
whose router ACL lets it subscribe ``zdrone-ops/*/*`` and hear and ask for the fleet's revisions, and
nothing else (no put, no queryable, no key that commands). Each GS seals its operations picture for
it (``zdrone.core.opspicture``); a part that does not open, replays, or is an old start of a GS is
dropped and counted (shown on the page). One thread (``Follower``) drains the inbox and merges the
parts into a ``FleetPicture`` under a lock, which checks each drone's signed word on who commands it
against the drone's signing keys over time and takes a GS's word only on the drones it is authorized
for. The same thread takes the fleet's revisions live (``zdrone.fleet.revisions``): a revoked GS
drops out at once (its parts no longer open), a rotated GS key must start anew, a rotated drone key
is in force at once and retires the old one (as at start: the last key the revisions held give a
drone is the one in force, heard under or not).

**Serving.** Starlette on uvicorn: ``/`` the page, ``/static/*`` its own JS and CSS (shipped in the
package, no CDN, no map tiles: the plan is drawn from the fleet's own geometry), ``/api/stream`` the
picture as server-sent events (msgspec JSON: ``init`` with the geometry and every track so far, then
``picture`` at most every ``PUSH_MIN_S`` when something changed and at least every ``PUSH_MAX_S``, so
staleness shows without news; one picture made per version for every stream), ``/report`` the run's
HTML report when ``--run`` names a folder that has one. The page reconnects by itself (the stream's
``retry``) when the server restarts, and shows every drone as stale while it has no stream or after
any error of its own. The server stays up under load: a connection must finish its TLS handshake and
send its request head within ``HEADER_TIMEOUT_S`` of accept, at most ``MAX_CONNECTIONS`` are open
(counted from accept) and ``MAX_STREAMS`` streams served at once; one more connection cuts the oldest
one without a whole request head, and one address holds ``MAX_HEADLESS_PER_ADDRESS`` of those at most
(``Gate``): a stranger holding half-open connections never locks the operator out. A request head is
at most ``MAX_HEAD_BYTES``, and the open-file limit is raised to the hard one at start.

**Exposure.** Loopback by default. Any other address needs ``--listen`` *and* a token (``--token-file
FILE`` or ``$ZDRONE_VIEW_TOKEN``; ``--token T`` works, warned about: ``ps`` shows it): every request
then carries it (``?token=`` once, kept in an HttpOnly, SameSite=Strict cookie, or an
``Authorization: Bearer`` header), compared in constant time. The ``Host`` header must name the
address served or a name given with ``--name`` (required with ``--listen 0.0.0.0``): a DNS-rebinding
page cannot read the view. TLS: ``--tls-cert``/``--tls-key`` (the guarded protocol's, once admitted),
or a reverse proxy that terminates TLS in front of a loopback view (README). Every response forbids outside sources
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

from zdrone.core.errors import ConfigError, UsageError
from zdrone.core.opspicture import OPS_MAX_BYTES, FleetPicture, OpsOpener, OpsReport, fleet_authorized, fleet_senders
from zdrone.fleet import keyexprs
from zdrone.net.shutdown import serve_signals

log = logging.getLogger(__name__)

#: The stream sends a picture at most this often when something changed ...
PUSH_MIN_S = 0.1
#: ... and at least this often (ages move on, staleness shows).
PUSH_MAX_S = 0.5
#: What the page waits before reconnecting a lost stream (ms).
RETRY_MS = 500
#: A connection must have sent a whole request head within this long of opening (or of its last
#: response): a client that trickles a header, or sends none, is cut off.
HEADER_TIMEOUT_S = 10.0
#: A connection whose peer reads nothing of what it is sent (its send buffer stays full: an unread response,
#: a pipeline of requests never read, a stream nobody reads) is cut after this long, served or not.
SEND_STALL_S = 10.0
#: An idle kept-alive connection is closed after this long.
KEEP_ALIVE_S = 5.0
#: Connections open at once, counted from accept (a TLS handshake included), at most; one more cuts
#: the oldest without a whole request head (``Gate``), or is cut at once when all are serving.
MAX_CONNECTIONS = 256
#: Connections without a whole request head (a TLS handshake included) one address holds at most; one
#: more cuts that address's oldest (``Gate``).
MAX_HEADLESS_PER_ADDRESS = 8
#: Picture streams served at once, at most; one more is answered 503 (the page retries).
MAX_STREAMS = 64
#: The largest request head taken (bytes).
MAX_HEAD_BYTES = 8192
#: The token's environment variable (a token on the command line is visible to every local user in ``ps``).
TOKEN_ENV = "ZDRONE_VIEW_TOKEN"
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
    token: str | None = None  # the token itself (``resolve_token``: from a file or the environment)
    run: str | None = None  # a run's folder: its report.html is linked
    viewer: str | None = None  # the viewer's name (default: the fleet's viewer whose secret is in the bundle)
    names: tuple[str, ...] = ()  # the host names a browser reaches the server by (its Host header)
    tls_cert: str | None = None  # serve HTTPS with this certificate chain (PEM) ...
    tls_key: str | None = None  # ... and this private key (PEM)


def check_exposure(listen: str | None, token: str | None, names: tuple[str, ...] = ()) -> str:
    """The address to bind: loopback unless ``--listen`` names another *and* a token is given; an
    unspecified address (``0.0.0.0``, ``::``) also needs the names a browser will use (``--name``)."""
    host = listen or "127.0.0.1"
    try:
        addr = ipaddress.ip_address(host)
    except ValueError:
        raise UsageError(f"--listen {host}: an IP address (e.g. 127.0.0.1)") from None
    if not addr.is_loopback and not token:
        raise UsageError(f"--listen {host}: not loopback; remote access needs a token "
                         f"(--token-file FILE or ${TOKEN_ENV}: a long random secret)")
    if token is not None and len(token) < 16:
        raise UsageError("the token: at least 16 characters")
    if addr.is_unspecified and not names:
        raise UsageError(f"--listen {host}: every address; name the host the browser uses (--name view.example.org, "
                         "repeatable): the Host header is checked against it")
    for n in names:
        if not n or (any(c in n for c in "/:@ ?#[]") and not _is_ip(n)):
            raise UsageError(f"--name {n!r}: a host name or an IP address, without port or scheme")
    return host


def _is_ip(text: str) -> bool:
    try:
        ipaddress.ip_address(text)
        return True
    except ValueError:
        return False


def allowed_hosts(host: str, port: int, names: tuple[str, ...] = ()) -> frozenset[str]:
    """The ``Host`` headers the server answers: the address it binds (unless it binds every address),
    ``localhost`` on loopback, and every name given, each with the port and without it (a reverse proxy
    in front, or the scheme's default port). Anything else (a DNS-rebinding page's name) gets 421."""
    out: set[str] = set()

    def add(h: str) -> None:
        h = h.lower()
        shown = f"[{h}]" if ":" in h else h
        out.update({shown, f"{shown}:{port}"})

    addr = ipaddress.ip_address(host)
    if not addr.is_unspecified:
        add(host)
    if addr.is_loopback:
        add("localhost")
    for n in names:
        add(n)
    return frozenset(out)


def resolve_token(token: str | None, token_file: str | None, environ: Any = None) -> str | None:
    """The token: from ``token_file`` (its first line; a file others may read is warned about), else
    ``--token`` (warned about: visible in ``ps``), else the environment (``ZDRONE_VIEW_TOKEN``)."""
    import os
    import stat

    environ = os.environ if environ is None else environ
    if token_file is not None:
        path = Path(token_file)
        try:
            mode = path.stat().st_mode
            lines = path.read_text().splitlines()
        except OSError as exc:
            raise UsageError(f"--token-file {token_file}: {exc.strerror or exc}") from None
        if mode & (stat.S_IRWXG | stat.S_IRWXO):
            log.warning("--token-file %s: readable by others (chmod 600 it)", token_file)
        got = lines[0].strip() if lines else ""
        if not got:
            raise UsageError(f"--token-file {token_file}: empty")
        return got
    if token is not None:
        log.warning("--token: the token is visible to every local user (ps); use --token-file or $%s", TOKEN_ENV)
        return token
    return environ.get(TOKEN_ENV) or None


def _geometry(fleet: Any) -> dict[str, Any]:
    home = fleet.home
    stations = [{"name": g, "lat": n.coverage.lat, "lon": n.coverage.lon, "radius_m": n.coverage.radius_m}
                for g, n in sorted(fleet.nodes.items()) if n.role == "gs" and n.coverage is not None]
    return {"home": None if home is None else {"lat": home.lat, "lon": home.lon}, "stations": stations}


class Follower:
    """The viewer's Zenoh side: the parts the GSs publish, opened and merged, and the fleet's revisions
    taken live (one thread)."""

    def __init__(self, opts: ViewOptions) -> None:
        from zdrone.net.runtime import NodeRuntime
        from zdrone.fleet.files import fleet_path, load_fleet
        from zdrone.fleet.revisions import RevisionChannel, signing_key_history

        fleet = load_fleet(opts.fleet)
        names = [opts.viewer] if opts.viewer else [
            v for v in fleet.viewers() if (fleet_path(opts.fleet).parent / "secrets" / f"{v}.json").exists()]
        if not names:
            raise ConfigError(f"{opts.fleet}: no viewer's secret here (export the viewer's bundle: zdrone fleet export V)")
        self.rt = NodeRuntime(opts.fleet, names[0], "viewer", opts.router, None)
        self.fleet = self.rt.fleet
        self.opener = OpsOpener(self.rt.secret.identity, names[0], fleet_senders(self.fleet))
        # each drone's signing keys over time: its attestations of who commands it are checked against
        # the last (the revision held names it), the earlier ones retired
        history = signing_key_history(opts.fleet)
        self.picture = FleetPicture(fleet_authorized(self.fleet),
                                    {d: history[d] for d in self.fleet.drones() if d in history},
                                    fleet_senders(self.fleet))
        self.lock = threading.Lock()
        self.stopping = threading.Event()  # the server is ending: the streams end (the page reconnects)
        self.rt.subscribe(keyexprs.ops_all(), "ops", keyexprs.gs_of_ops, limit=OPS_MAX_BYTES)
        # the fleet's revisions, as every node hears them (the router lets the viewer subscribe and ask,
        # never publish): a revoked GS drops out, a rotated key is taken, without a restart
        self.revisions = RevisionChannel(self.rt, opts.fleet, publisher=False)
        self._thread = threading.Thread(target=self._run, name="follower", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        while self.rt.running:
            try:
                self.rt.poll_paths()
                self.revisions.serve(time.monotonic())
                self.rt.inbox.drain(0.1, self._on_item)
            except Exception:  # last resort: the view goes on (counted, logged with its stack)
                log.exception("follower")
                self.opener.drops["internal_error"] += 1

    def _on_item(self, kind: str, gs: str, data: Any, now: float) -> None:
        from zdrone.fleet.revisions import KINDS, RevisionAccepted

        if kind in KINDS:
            got = self.revisions.on_inbox(kind, data)
            if isinstance(got, RevisionAccepted):
                with self.lock:
                    self.apply_fleet(got.fleet)
            return
        with self.lock:
            got_part = self.opener.open(gs, keyexprs.ops(gs), bytes(data), time.monotonic(), time.time())
            if isinstance(got_part, OpsReport):
                self.picture.on_report(got_part, time.monotonic(), time.time())

    def apply_fleet(self, fleet: Any) -> None:
        """A fleet revision in force (under ``lock``): the GSs whose pictures open (a revoked one is
        dropped, a rotated one starts anew under its new key), who is authorized for which drone, and
        each drone's newest signing key."""
        self.fleet = self.rt.fleet = fleet
        self.opener.set_senders(fleet_senders(fleet))
        self.picture.set_fleet(fleet_authorized(fleet), fleet_senders(fleet))
        for d in fleet.drones():
            key = fleet.nodes[d].signing_public_bytes
            if key is not None:
                self.picture.add_key(d, key)  # in force at once: the keys before it retired
        log.warning("fleet revision %d in force in the view", self.revisions.keeper.number)

    def snapshot(self) -> dict[str, Any]:
        with self.lock:
            snap = self.picture.snapshot(time.monotonic(), time.time())
            snap["drops"] = (dict(self.opener.drops) | dict(self.picture.drops) | dict(self.picture.check.counts)
                             | {k: v for k, v in self.rt.inbox.stats().items() if v})
            snap["opened"] = self.opener.opened
            snap["revision"] = self.revisions.keeper.number
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
        from zdrone.core import records as rec

        self.rt.close({}, rec.Closed)


def build_app(follower: Any, opts: ViewOptions, host: str) -> Any:
    """The Starlette application (``follower``: ``snapshot()``, ``tracks()``, ``version``, ``fleet``,
    ``stopping``)."""
    from starlette.applications import Starlette
    from starlette.requests import Request
    from starlette.responses import PlainTextResponse, Response, StreamingResponse
    from starlette.routing import Route

    enc = msgspec.json.Encoder()
    files = {name: (resources.files("zdrone.view") / "static" / name).read_bytes() for name in STATIC}
    types = {"html": "text/html; charset=utf-8", "js": "text/javascript; charset=utf-8", "css": "text/css; charset=utf-8"}
    hosts = allowed_hosts(host, opts.port, opts.names)
    run = Path(opts.run) if opts.run else None
    secure = opts.tls_cert is not None
    streams = {"open": 0}
    # one picture per version (and per ``PUSH_MIN_S`` at most) for every stream: N pages cost one snapshot
    shared: dict[str, Any] = {"version": None, "made": float("-inf"), "data": b""}

    def refused(request: Request) -> Response | None:
        if request.headers.get("host", "").lower() not in hosts:
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
            # a cookie carries it from here (the page takes it out of the address bar)
            resp.set_cookie(COOKIE, opts.token, httponly=True, samesite="strict", secure=secure)
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

    def picture(now: float) -> tuple[int, bytes]:
        """The picture every stream sends now: made anew when the follower moved on, at most every
        ``PUSH_MIN_S``, and when the last one is ``PUSH_MAX_S`` old (ages move on)."""
        version = follower.version
        if (version != shared["version"] and now - shared["made"] >= PUSH_MIN_S) or now - shared["made"] >= PUSH_MAX_S:
            snap = follower.snapshot()
            snap["report"] = has_report()
            snap["server_time"] = time.time()
            shared.update(version=version, made=now, data=b"event: picture\ndata: " + enc.encode(snap) + b"\n\n")
        return shared["version"], shared["data"]

    async def stream(request: Request) -> Response:
        bad = refused(request)
        if bad is not None:
            return bad
        if streams["open"] >= MAX_STREAMS:
            return PlainTextResponse("too many streams", status_code=503, headers={**SECURITY_HEADERS, "Retry-After": "5"})
        streams["open"] += 1

        async def events() -> Any:
            try:
                init = {"geometry": _geometry(follower.fleet), "tracks": follower.tracks()}
                yield b"retry: %d\nevent: init\ndata: " % RETRY_MS + enc.encode(init) + b"\n\n"
                seen, sent = None, float("-inf")
                while not follower.stopping.is_set() and not await request.is_disconnected():
                    now = time.monotonic()
                    if (follower.version != seen and now - sent >= PUSH_MIN_S) or now - sent >= PUSH_MAX_S:
                        seen, data = picture(now)
                        sent = now
                        yield data
                    await asyncio.sleep(0.02)
            finally:
                streams["open"] -= 1

        return StreamingResponse(events(), media_type="text/event-stream", headers={**SECURITY_HEADERS, "X-Accel-Buffering": "no"})

    return Starlette(routes=[Route("/", page), Route("/static/{name}", asset), Route("/api/stream", stream),
                             Route("/report", report)])


class Gate:
    """Who holds the server's connections, counted from accept (a TLS handshake included): at most
    ``cap`` open. A connection is *headless* while it has no whole request head to serve (in its TLS
    handshake, sending its head, or idle between requests): one more connection cuts its own
    address's oldest headless one when that address holds ``per_address`` of them, else, when ``cap``
    are open, the oldest headless one of all; it is refused only when every open connection is
    serving a request. Pure: the caller cuts what ``admit`` returns."""

    def __init__(self, cap: int, per_address: int) -> None:
        self.cap, self.per_address = cap, per_address
        self.open: set[Any] = set()
        self.headless: dict[Any, Any] = {}  # connection -> its address, oldest first
        self.by_address: dict[Any, dict[Any, None]] = {}  # address -> its headless connections, oldest first
        self.evicted = self.refused = 0

    def admit(self, conn: Any, address: Any) -> list[Any] | None:
        """``conn``, just accepted from ``address``, is in: the connections to cut for it (forgotten
        here already); None: it is refused (every open connection is serving)."""
        mine = self.by_address.get(address)
        if mine is not None and len(mine) >= self.per_address:
            cut = [next(iter(mine))]
        elif len(self.open) >= self.cap:
            if not self.headless:
                self.refused += 1
                return None
            cut = [next(iter(self.headless))]
        else:
            cut = []
        for c in cut:
            self.gone(c)
        self.evicted += len(cut)
        self.open.add(conn)
        self.waiting(conn, address)
        return cut

    def serving(self, conn: Any) -> None:
        """A whole request head came: ``conn`` is not cut for another while it is served."""
        address = self.headless.pop(conn, None)
        if address is not None:
            self._forget(address, conn)

    def waiting(self, conn: Any, address: Any) -> None:
        """``conn`` waits for a request head (accepted, or its response complete): headless, the youngest."""
        if conn in self.open and conn not in self.headless:
            self.headless[conn] = address
            self.by_address.setdefault(address, {})[conn] = None

    def gone(self, conn: Any) -> None:
        self.open.discard(conn)
        self.serving(conn)

    def _forget(self, address: Any, conn: Any) -> None:
        mine = self.by_address[address]
        del mine[conn]
        if not mine:
            del self.by_address[address]


def guarded_protocol(tls: Any = None) -> type:
    """uvicorn's h11 protocol behind an admission gate (``Gate``: one per server), with TLS done here
    when ``tls`` (an ``ssl.SSLContext``) is given: a connection is counted and timed from accept, its
    TLS handshake included; it must have sent a whole request head within ``HEADER_TIMEOUT_S`` of
    accept (or of its last response), whatever it trickles meanwhile (uvicorn's own keep-alive timer
    restarts at every byte), and the handshake is cut at the same deadline. One more connection than
    ``MAX_CONNECTIONS``, or than ``MAX_HEADLESS_PER_ADDRESS`` headless from one address, cuts the
    oldest headless one (``Gate``), so a stranger holding half-open connections never locks out the
    operator's. A TLS handshake is started only once admitted: memory is bounded by the gate."""
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class Guarded(H11Protocol):  # type: ignore[misc]
        gate = Gate(MAX_CONNECTIONS, MAX_HEADLESS_PER_ADDRESS)
        timed_out = 0  # connections cut for want of a request head (a TLS handshake included)
        stalled = 0  # connections cut for reading nothing of what they were sent (``SEND_STALL_S``)

        def connection_made(self, transport: Any) -> None:
            if getattr(self, "_raw", None) is not None:  # the TLS transport, once the handshake is done
                super().connection_made(transport)
                early, self._early = self._early, []
                for data in early:  # what the client sent with its handshake's end
                    self.data_received(data)
                return
            self._raw, self._early, self._served = transport, [], False
            self._head_timer: asyncio.TimerHandle | None = None
            peer = transport.get_extra_info("peername")
            self._address = peer[0] if isinstance(peer, tuple) else peer
            cut = Guarded.gate.admit(self, self._address)
            if cut is None:  # every open connection is serving a request
                transport.abort()
                return
            for conn in cut:
                conn._cut()
            if cut and (Guarded.gate.evicted <= 5 or Guarded.gate.evicted % 1000 == 0):
                log.warning("view: a connection without a request head cut for a new one (%d so far)",
                            Guarded.gate.evicted)
            self._arm_head()
            if tls is None:
                super().connection_made(transport)
            else:
                transport.pause_reading()  # its first bytes are the handshake's: ``start_tls`` reads them
                self._tls_task = self.loop.create_task(self._handshake(transport))

        def _cut(self) -> None:
            """Cut at once (the gate's choice, or the deadline): a TLS handshake under way is cancelled
            (``start_tls`` then drops its TLS state at once, not at its own timeout)."""
            task, self._tls_task = getattr(self, "_tls_task", None), None  # no cycle through its CancelledError
            if task is not None and not task.done():
                task.cancel()
            # closed here, not by the task: one cancelled before its first step never runs its own
            # ``except`` (its socket and this protocol stayed open until the head deadline)
            self._cancel_head()
            self._cancel_stall()
            self._raw.abort()

        async def _handshake(self, raw: Any) -> None:
            left = self._head_timer.when() - self.loop.time() if self._head_timer is not None else 0.0
            try:
                wrapped = await self.loop.start_tls(raw, self, tls, server_side=True,
                                                    ssl_handshake_timeout=max(0.01, left))
            except asyncio.CancelledError:  # cut (``_cut``), or the server ends
                raw.abort()
                self._gone()
                raise
            except Exception:  # refused, timed out, or cut (by the gate, at the deadline): start_tls closed it
                self._gone()
                return
            if wrapped is None or raw.is_closing():
                self._gone()
                return
            self.connection_made(wrapped)

        def data_received(self, data: bytes) -> None:
            if self.transport is None:  # TLS: data may come before ``connection_made`` (the handshake's end)
                self._early.append(data)
                return
            super().data_received(data)
            if not self._served and self.cycle is not None and not self.cycle.response_complete:
                self._served = True  # a whole request head: served, not cut for another
                self._cancel_head()
                Guarded.gate.serving(self)

        def _arm_head(self) -> None:
            self._cancel_head()
            self._head_timer = self.loop.call_later(HEADER_TIMEOUT_S, self._head_timeout)

        def _cancel_head(self) -> None:
            if self._head_timer is not None:
                self._head_timer.cancel()
                self._head_timer = None

        def _head_timeout(self) -> None:
            self._head_timer = None
            serving = self.cycle is not None and not self.cycle.response_complete
            if not serving and not self._raw.is_closing():
                Guarded.timed_out += 1
                self._cut()

        def pause_writing(self) -> None:
            """The peer reads nothing of what we send (our send buffer is full): it has ``SEND_STALL_S`` to
            read again, or it is cut (a served connection is not cut for another: an unread response,
            a pipeline of them or an unread stream would otherwise hold its slot for ever)."""
            super().pause_writing()
            if getattr(self, "_stall_timer", None) is None:
                self._stall_timer = self.loop.call_later(SEND_STALL_S, self._stalled)

        def resume_writing(self) -> None:
            super().resume_writing()
            self._cancel_stall()

        def _cancel_stall(self) -> None:
            timer, self._stall_timer = getattr(self, "_stall_timer", None), None
            if timer is not None:
                timer.cancel()

        def _stalled(self) -> None:
            self._stall_timer = None
            if not self._raw.is_closing():
                Guarded.stalled += 1
                if Guarded.stalled <= 5 or Guarded.stalled % 1000 == 0:
                    log.warning("view: a connection that read nothing for %g s cut (%d so far)", SEND_STALL_S,
                                Guarded.stalled)
                self._cut()

        def on_response_complete(self) -> None:
            super().on_response_complete()  # a pipelined request may be served at once
            if not self.transport.is_closing() and (self.cycle is None or self.cycle.response_complete):
                self._served = False
                Guarded.gate.waiting(self, self._address)
                self._arm_head()

        def _gone(self) -> None:
            self._cancel_head()
            self._cancel_stall()
            Guarded.gate.gone(self)

        def connection_lost(self, exc: Exception | None) -> None:
            self._gone()
            if self.transport is not None:  # else refused, or gone before its TLS handshake began
                super().connection_lost(exc)

    return Guarded


def raise_file_limit() -> int:
    """The soft limit on open files raised to the hard one (each connection is a file descriptor); the
    limit now in force."""
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = hard if hard != resource.RLIM_INFINITY else max(soft, 1 << 16)
    if soft != resource.RLIM_INFINITY and soft < want:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))
            soft = want
        except (ValueError, OSError) as exc:
            log.warning("view: the open-file limit stays %d: %s", soft, exc)
    return soft


def server_config(app: Any, opts: ViewOptions, host: str) -> Any:
    """uvicorn's configuration: the guarded protocol, the timeouts, TLS when asked."""
    import uvicorn

    tls = None
    if opts.tls_cert:  # done by the guarded protocol, not by uvicorn (its handshake is counted and timed from accept)
        import ssl

        tls = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        tls.load_cert_chain(opts.tls_cert, opts.tls_key)
    return uvicorn.Config(app, host=host, port=opts.port, log_level="warning", lifespan="off", access_log=False,
                          timeout_graceful_shutdown=1, http=guarded_protocol(tls), timeout_keep_alive=KEEP_ALIVE_S,
                          h11_max_incomplete_event_size=MAX_HEAD_BYTES, backlog=MAX_CONNECTIONS, loop="asyncio",
                          ws="none")  # no protocol switch: every connection stays the gate's


def run_view(opts: ViewOptions) -> int:
    import uvicorn

    host = check_exposure(opts.listen, opts.token, opts.names)
    if (opts.tls_cert is None) != (opts.tls_key is None):
        raise UsageError("--tls-cert and --tls-key go together")
    if not ipaddress.ip_address(host).is_loopback and opts.tls_cert is None:
        log.warning("view: serving %s over plain HTTP: the token and the picture cross the network in clear "
                    "(--tls-cert/--tls-key, or a reverse proxy with TLS in front: README)", host)
    limit = raise_file_limit()
    if limit < MAX_CONNECTIONS + 64:
        log.warning("view: only %d files may be open (MAX_CONNECTIONS %d)", limit, MAX_CONNECTIONS)
    follower = Follower(opts)
    follower.start()
    server = uvicorn.Server(server_config(build_app(follower, opts, host), opts, host))

    def announce() -> None:
        while not server.started and not server.should_exit:
            time.sleep(0.02)
        if server.started:
            shown = f"[{host}]" if ":" in host else host
            scheme = "https" if opts.tls_cert else "http"
            print(f"zdrone view: {scheme}://{shown}:{opts.port}/ (viewer {follower.rt.name}, router {opts.router})", flush=True)

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
    token = resolve_token(args.token, args.token_file)
    return run_view(ViewOptions(fleet=args.fleet, router=args.router, port=args.port, listen=args.listen,
                                token=token, run=args.run, viewer=args.id, names=tuple(args.name or ()),
                                tls_cert=args.tls_cert, tls_key=args.tls_key))


def add_view(sub: Any, func: Any) -> None:
    """``zdrone view``'s parser."""
    p = sub.add_parser("view", help="live web view of the fleet: who commands which drone, every link (read-only)")
    p.add_argument("--fleet", default="fleet", help="the viewer's bundle (or a fleet directory holding its secret)")
    p.add_argument("--router", default="tcp/127.0.0.1:7447", help="Zenoh router endpoint")
    p.add_argument("--id", default=None, help="the viewer's name in the fleet (default: the one whose secret is here)")
    p.add_argument("--port", type=int, default=8470, help="HTTP port (default 8470)")
    p.add_argument("--listen", default=None, metavar="ADDR",
                   help="address to serve on (default 127.0.0.1); any other needs a token; 0.0.0.0 or :: also --name")
    p.add_argument("--name", action="append", default=None, metavar="HOST",
                   help="a host name (or address) browsers reach the view by: the Host header must name one (repeatable)")
    p.add_argument("--token-file", default=None, metavar="FILE",
                   help=f"a file holding the secret every request must carry (?token= once, then a cookie); "
                        f"or set ${TOKEN_ENV}")
    p.add_argument("--token", default=None, help=f"the secret itself (visible in ps: prefer --token-file or ${TOKEN_ENV})")
    p.add_argument("--tls-cert", default=None, metavar="PEM", help="serve HTTPS: the certificate chain (with --tls-key)")
    p.add_argument("--tls-key", default=None, metavar="PEM", help="serve HTTPS: the private key")
    p.add_argument("--run", default=None, metavar="DIR", help="a run folder: its report.html is linked from the page")
    p.set_defaults(func=func)
