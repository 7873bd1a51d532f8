"""``zdrone view``'s server on a real socket, in-process (``tests.viewfake``): exposure (the Host
header, the token and where it comes from), and staying up (a request head's deadline, a bound on
connections and streams, one picture made for every stream)."""

from __future__ import annotations

import http.client
import logging
import os
import select
import socket

import pytest

from tests.procs import wait_until
from tests.viewfake import FakeFollower, row, serving
from zdrone.core.errors import UsageError
from zdrone.view import server as srv
from zdrone.view.server import TOKEN_ENV, ViewOptions, allowed_hosts, check_exposure, resolve_token

TOKEN = "t" * 32


def _get(port: int, path: str = "/", host: str | None = None, token: str | None = None) -> int:
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        headers = {"Host": host or f"127.0.0.1:{port}"}
        if token:
            headers["Authorization"] = f"Bearer {token}"
        c.request("GET", path, headers=headers)
        return c.getresponse().status
    finally:
        c.close()


def test_the_view_serves_loopback_unless_an_address_and_a_token_are_given():
    assert check_exposure(None, None) == "127.0.0.1"
    with pytest.raises(UsageError, match="needs a token"):
        check_exposure("10.0.0.1", None)
    with pytest.raises(UsageError, match="at least 16"):
        check_exposure("10.0.0.1", "short")
    assert check_exposure("10.0.0.1", TOKEN) == "10.0.0.1"
    with pytest.raises(UsageError, match="--name"):  # every address: the names the browser uses are needed
        check_exposure("0.0.0.0", TOKEN)
    assert check_exposure("0.0.0.0", TOKEN, ("view.example.org",)) == "0.0.0.0"
    with pytest.raises(UsageError, match="--name"):
        check_exposure("0.0.0.0", TOKEN, ("http://view.example.org:80",))


def test_listening_on_every_address_answers_the_names_given_and_refuses_others():
    """Found: ``--listen 0.0.0.0 --token`` refused every client 421 (the one Host allowed was 0.0.0.0:PORT)."""
    assert "0.0.0.0:8470" not in allowed_hosts("0.0.0.0", 8470, ("view.example.org",))
    assert {"view.example.org:8470", "view.example.org"} <= allowed_hosts("0.0.0.0", 8470, ("View.Example.org",))
    opts = ViewOptions(fleet="-", router="-", listen="0.0.0.0", token=TOKEN, names=("view.example.org", "10.1.2.3"))
    with serving(FakeFollower([row("d1")]), opts, host="0.0.0.0") as port:
        assert _get(port, host=f"view.example.org:{port}", token=TOKEN) == 200  # a real remote browser
        assert _get(port, host="view.example.org", token=TOKEN) == 200  # behind a reverse proxy
        assert _get(port, host=f"10.1.2.3:{port}", token=TOKEN) == 200
        assert _get(port, host=f"evil.example:{port}", token=TOKEN) == 421  # a DNS-rebinding page's name
        assert _get(port, host=f"view.example.org:{port}") == 401
        assert _get(port, host=f"view.example.org:{port}", token="x" * 32) == 401


class _Caught(logging.Handler):
    """The view server's own warnings, caught on its logger (whatever another test in this worker did
    to the root logger or to propagation)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


def test_the_token_comes_from_a_file_or_the_environment_and_on_the_command_line_is_warned_about(tmp_path):
    """Found: the token could only be given on the command line (``ps`` shows it to every local user)."""
    path = tmp_path / "token"
    path.write_text(TOKEN + "\n")
    os.chmod(path, 0o600)
    logger = logging.getLogger("zdrone.view.server")
    caught, was = _Caught(), (logger.disabled, logger.level)
    logger.addHandler(caught)
    logger.disabled = False
    logger.setLevel(logging.WARNING)
    try:
        assert resolve_token(None, str(path), {}) == TOKEN
        assert not caught.lines
        os.chmod(path, 0o644)
        assert resolve_token(None, str(path), {}) == TOKEN
        assert any("readable by others" in x for x in caught.lines)
        caught.lines.clear()
        assert resolve_token(None, None, {TOKEN_ENV: TOKEN}) == TOKEN and not caught.lines
        assert resolve_token(TOKEN, None, {}) == TOKEN and any("visible" in x for x in caught.lines)
    finally:
        logger.removeHandler(caught)
        logger.disabled, _ = was
        logger.setLevel(was[1])
    assert resolve_token(None, None, {}) is None
    with pytest.raises(UsageError, match="empty"):
        (tmp_path / "empty").write_text("\n")
        resolve_token(None, str(tmp_path / "empty"), {})


def test_a_client_that_never_finishes_its_request_head_is_cut_off(monkeypatch):
    """Found: 1100 partial requests held 1100 file descriptors for good (no request-head deadline)."""
    monkeypatch.setattr(srv, "HEADER_TIMEOUT_S", 0.3)
    with serving(FakeFollower()) as port:
        silent = socket.create_connection(("127.0.0.1", port))
        partial = socket.create_connection(("127.0.0.1", port))
        partial.sendall(b"GET / HTTP/1.1\r\nHo")
        for s in (silent, partial):
            s.settimeout(10)
            assert s.recv(100) == b""  # closed by the server, well before 10 s
            s.close()
        assert _get(port) == 200  # a whole request is served


def test_connections_beyond_the_limit_cut_the_oldest_headless_and_the_file_limit_is_raised(monkeypatch):
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    assert srv.raise_file_limit() == (hard if hard != resource.RLIM_INFINITY else max(soft, 1 << 16))
    monkeypatch.setattr(srv, "MAX_CONNECTIONS", 4)
    with serving(FakeFollower()) as port:
        socks = [socket.create_connection(("127.0.0.1", port)) for _ in range(10)]

        def cut() -> list[socket.socket]:
            ready, _, _ = select.select(socks, [], [], 0.05)
            return ready

        assert wait_until(lambda: len(cut()) >= 6, 5)
        gone = cut()
        assert gone == socks[:6] and all(s.recv(10) == b"" for s in gone)  # the oldest cut at once, nothing said
        kept = socks[6:]
        for s in kept:  # the newest four are served
            s.sendall(f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
            s.settimeout(5)
            assert s.recv(12) == b"HTTP/1.1 200"
        for s in socks:
            s.close()


def _pictures(port: int, want: int) -> int:
    """Reads one stream until it brought ``want`` pictures; how many it brought."""
    c = socket.create_connection(("127.0.0.1", port))
    c.settimeout(10)
    c.sendall(f"GET /api/stream HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
    got = b""
    while got.count(b"event: picture") < want:
        chunk = c.recv(65536)
        if not chunk:
            break
        got += chunk
    c.close()
    return got.count(b"event: picture")


def test_every_stream_shares_one_picture_per_version_and_streams_are_bounded(monkeypatch):
    import concurrent.futures

    monkeypatch.setattr(srv, "PUSH_MAX_S", 0.1)
    follower = FakeFollower([row("d1")])
    with serving(follower) as port:
        with concurrent.futures.ThreadPoolExecutor(6) as pool:
            counts = list(pool.map(lambda _: _pictures(port, 5), range(6)))
        assert counts == [5] * 6
        assert follower.snapshots < 20  # 30 pictures sent: made once for every stream (about 6 times, not 30)
        monkeypatch.setattr(srv, "MAX_STREAMS", 0)
        assert _get(port, "/api/stream") == 503


def test_the_gate_cuts_the_oldest_headless_connection_and_holds_each_address_to_its_own_few():
    gate = srv.Gate(cap=4, per_address=2)
    assert gate.admit("op1", "10.0.0.1") == [] and gate.admit("a1", "10.0.0.9") == []
    gate.serving("op1")  # the operator's whole head came: served, never cut for another
    assert gate.admit("a2", "10.0.0.9") == []
    assert gate.admit("a3", "10.0.0.9") == ["a1"]  # the stranger's third headless one cuts its own oldest
    assert gate.admit("b1", "10.0.0.7") == []  # 4 open: op1 (serving), a2, a3, b1
    assert gate.admit("op2", "10.0.0.1") == ["a2"]  # at the cap: the oldest headless of all goes, not the newcomer
    gate.waiting("op1", "10.0.0.1")  # op1's response done: headless again, the youngest
    assert gate.admit("c1", "10.0.0.5") == ["a3"]
    for c in ("b1", "op2", "op1", "c1"):
        gate.serving(c)
    assert gate.admit("d1", "10.0.0.4") is None and gate.refused == 1  # every one serving: the newcomer refused
    gate.gone("b1")
    assert gate.admit("d1", "10.0.0.4") == [] and len(gate.open) == 4 and gate.by_address == {"10.0.0.4": {"d1": None}}


def test_half_open_heads_held_and_renewed_never_lock_the_operator_out(monkeypatch):
    """Found: 256 connections with half a request head, reopened when cut, made the page load 0/60."""
    monkeypatch.setattr(srv, "MAX_CONNECTIONS", 6)
    monkeypatch.setattr(srv, "MAX_HEADLESS_PER_ADDRESS", 100)  # one address here: the global rule under test
    with serving(FakeFollower()) as port:
        held = []
        for _ in range(3):  # the stranger fills the server three times over, half a head on each
            for _ in range(6):
                s = socket.create_connection(("127.0.0.1", port))
                s.sendall(b"GET / HTTP/1.1\r\nHo")
                held.append(s)
            assert _get(port) == 200  # the operator's connection, the newest, is served
        for s in held:
            s.close()


def test_one_address_holds_few_headless_connections_the_others_are_served(monkeypatch):
    monkeypatch.setattr(srv, "MAX_HEADLESS_PER_ADDRESS", 3)
    with serving(FakeFollower()) as port:
        socks = [socket.create_connection(("127.0.0.1", port)) for _ in range(10)]
        assert wait_until(lambda: len(select.select(socks, [], [], 0.05)[0]) >= 7, 5)
        gone = select.select(socks, [], [], 0.05)[0]
        assert gone == socks[:7] and all(s.recv(10) == b"" for s in gone)  # the oldest cut, the newest three kept
        for s in socks:
            s.close()


def _cut_off(s: socket.socket) -> bool:
    """Whether the server closed ``s`` saying nothing (a FIN, or a reset when it left bytes unread)."""
    try:
        return s.recv(10) == b""
    except ConnectionResetError:
        return True


def _self_signed(tmp_path) -> tuple[str, str]:
    from cryptography.hazmat.primitives import serialization

    from zdrone.fleet.tls import issue, make_ca

    ca, ca_key = make_ca()
    cert, key = issue(ca, ca_key, "view", ("127.0.0.1",))
    (tmp_path / "c.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    (tmp_path / "k.pem").write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                                       serialization.NoEncryption()))
    return str(tmp_path / "c.pem"), str(tmp_path / "k.pem")


def test_tls_handshakes_are_counted_and_timed_from_accept(monkeypatch, tmp_path):
    """Found: 1500 half-open TLS handshakes were held 60 s past the connection cap (the view 66 -> 519 MB)."""
    import ssl

    monkeypatch.setattr(srv, "HEADER_TIMEOUT_S", 0.5)
    monkeypatch.setattr(srv, "MAX_CONNECTIONS", 4)
    cert, key = _self_signed(tmp_path)
    opts = ViewOptions(fleet="-", router="-", tls_cert=cert, tls_key=key)
    with serving(FakeFollower(), opts) as port:
        half = [socket.create_connection(("127.0.0.1", port)) for _ in range(10)]  # no ClientHello, ever
        for s in half[:5]:
            s.sendall(b"\x16\x03\x01\x00\xc8\x01")  # half a ClientHello
        ctx = ssl.create_default_context(cafile=None)
        ctx.check_hostname, ctx.verify_mode = False, ssl.CERT_NONE
        c = http.client.HTTPSConnection("127.0.0.1", port, timeout=5, context=ctx)
        c.request("GET", "/", headers={"Host": f"127.0.0.1:{port}"})
        assert c.getresponse().status == 200  # the operator's handshake and request, under 10 half-open ones
        c.close()
        assert wait_until(lambda: len(select.select(half, [], [], 0.05)[0]) == 10, 3)  # all cut, by the cap or at 0.5 s
        assert all(_cut_off(s) for s in half)
        for s in half:
            s.close()


def test_connections_that_read_nothing_of_their_responses_are_cut_and_never_lock_the_operator_out(monkeypatch):
    """Found by an attacker's review: 256 connections each pipelining 1 500 requests and reading none of
    the answers stayed "serving" (uvicorn waits for the send buffer to drain, with no deadline), the gate
    never cut them and every new connection was refused, the operator's with its token too."""
    monkeypatch.setattr(srv, "MAX_CONNECTIONS", 4)
    monkeypatch.setattr(srv, "SEND_STALL_S", 0.5)
    with serving(FakeFollower()) as port:
        held = []
        for _ in range(4):
            s = socket.socket()
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 2048)
            s.connect(("127.0.0.1", port))
            s.setblocking(False)
            req = f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode()
            try:
                for _ in range(20000):  # many requests, never a byte read back (until the socket is full)
                    s.send(req)
            except BlockingIOError:
                pass
            held.append(s)

        def served() -> bool:
            try:
                return _get(port) == 200
            except OSError:
                return False
        assert wait_until(served, timeout=10.0), "the operator stayed locked out"  # once the stalled ones are cut
        for s in held:
            s.close()
