"""Policy service: the decision service the robot queries every control period (HTTP + JSON).

Standard library only (``http.server.ThreadingHTTPServer``) plus NumPy and
``daddpg_jax.deploy.policy``: no web framework to install on the robot computer, one thread per
connection, persistent (HTTP/1.1 keep-alive) connections. Loopback (127.0.0.1) by default.

Endpoints
    POST /act    {"observation": [[25 floats], [25 floats]], "desired_goal": [[3], [3]],
                  "id": optional int or short string, echoed back}
                 -> 200 {"action": [8 floats], "per_arm": [[4], [4]], "latency_ms": float,
                         "id": ...}
    GET /health  -> 200 {"status": "ok", "requests": n, "errors": n, "timeouts": n,
                         "refused": n, "connections": n, "uptime_s": s}
    GET /info    -> 200 task, algo, format version, observation layout, env settings, ...

Malformed requests get a 4xx and ``{"error": "...", "status": code}``: 400 bad JSON, missing or
unknown fields, wrong types or shapes, NaN/inf, nesting deeper than ``max_depth``; 404 unknown
path; 405 wrong method; 408 the request line, headers and body not received within
``request_timeout`` seconds of the request's first byte; 411 no Content-Length; 413 body over
``max_body`` bytes (answered from the header; see below); 415 a Content-Type other than JSON;
503 ``max_connections`` connections already open. An unexpected exception answers 500; the
server keeps serving in every case.

Limits (``ServiceLimits``): every read of a request is bounded by the request's deadline, so a
client that trickles bytes holds its thread for ``request_timeout`` seconds at most; a
keep-alive connection idle for ``idle_timeout`` seconds between requests is closed; a
connection beyond ``max_connections`` gets 503 from a small pool of refusal threads instead of
a handler thread. After any answer that closes the connection (413, 408, 411, 503, ...) the
server closes with lingering: it sends the answer, shuts down its sending side, and reads and
discards what the client still sends (at most ``max_drain`` bytes, until the request's deadline
or ``LINGER_S`` seconds, whichever is later) before closing, so that a client that sends its
whole body before reading (``http.client``, ``requests``) receives the 413 instead of a
connection reset.
"""

from __future__ import annotations

import http.client
import io
import json
import math
import socket
import threading
import time
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import numpy as np

from daddpg_jax.deploy import NumpyPolicy

MAX_BODY = 64 * 1024
MAX_DEPTH = 8
REQUEST_TIMEOUT_S = 5.0
IDLE_TIMEOUT_S = 10.0
MAX_CONNECTIONS = 32
MAX_DRAIN = 64 * 1024 * 1024
LINGER_S = 0.5  # least time a closing connection is drained after its answer
REFUSAL_THREADS = 8  # connections over the cap answered 503 at once; beyond, closed unanswered
REQUEST_FIELDS = ("observation", "desired_goal", "id")


@dataclass(frozen=True)
class ServiceLimits:
    """What one request or client may use (all configurable: ``PolicyServer`` and daddpg-serve).

    max_body: largest request body, bytes; max_depth: deepest JSON nesting; request_timeout: s
    from a request's first byte to the end of its body; idle_timeout: s a keep-alive connection
    may wait between requests; max_connections: open connections served at once; max_drain:
    bytes read and discarded from a connection closed after an error.
    """

    max_body: int = MAX_BODY
    max_depth: int = MAX_DEPTH
    request_timeout: float = REQUEST_TIMEOUT_S
    idle_timeout: float = IDLE_TIMEOUT_S
    max_connections: int = MAX_CONNECTIONS
    max_drain: int = MAX_DRAIN

    def __post_init__(self):
        for name in ("max_body", "max_depth", "max_connections"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)!r}")
        for name in ("request_timeout", "idle_timeout"):
            v = float(getattr(self, name))
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be a positive number of seconds, got {v!r}")
        if int(self.max_drain) < 0:
            raise ValueError(f"max_drain must be >= 0, got {self.max_drain!r}")


class RequestError(Exception):
    def __init__(self, status: int, message: str, close: bool = False):
        super().__init__(message)
        self.status = status
        self.message = message
        self.close = close


class _DeadlinePassed(Exception):
    """The request's deadline passed before all of it arrived."""


def json_depth_exceeds(body: bytes, max_depth: int) -> bool:
    """True when arrays/objects nest deeper than ``max_depth`` (strings are skipped)."""
    if body.count(b"[") + body.count(b"{") <= max_depth:
        return False
    depth, in_str, esc = 0, False, False
    for ch in body:
        if in_str:
            if esc:
                esc = False
            elif ch == 0x5C:  # backslash
                esc = True
            elif ch == 0x22:  # quote
                in_str = False
        elif ch == 0x22:
            in_str = True
        elif ch in (0x5B, 0x7B):  # [ {
            depth += 1
            if depth > max_depth:
                return True
        elif ch in (0x5D, 0x7D):
            depth -= 1
    return False


def _reject_constant(name):
    raise ValueError(f"{name} is not valid JSON (non-finite numbers are refused)")


def parse_matrix(name: str, value: Any, rows: int, cols: int) -> np.ndarray:
    """A JSON value that must be ``rows`` lists of ``cols`` finite numbers -> float32 array."""
    if not isinstance(value, list) or len(value) != rows:
        got = f"a list of {len(value)}" if isinstance(value, list) else type(value).__name__
        raise RequestError(400, f"'{name}' must be a list of {rows} rows of {cols} numbers; "
                                f"got {got}")
    out = np.empty((rows, cols), np.float64)
    for i, row in enumerate(value):
        if not isinstance(row, list) or len(row) != cols:
            got = f"a list of {len(row)}" if isinstance(row, list) else type(row).__name__
            raise RequestError(400, f"'{name}'[{i}] must be a list of {cols} numbers; got {got}")
        for j, x in enumerate(row):
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise RequestError(400, f"'{name}'[{i}][{j}] must be a number, got "
                                        f"{type(x).__name__}")
            if isinstance(x, float) and not math.isfinite(x):
                raise RequestError(400, f"'{name}'[{i}][{j}] is not finite")
            if isinstance(x, int) and abs(x) > 1e300:
                raise RequestError(400, f"'{name}'[{i}][{j}] is out of range")
            out[i, j] = x
    return out.astype(np.float32)


def check_fields(req: dict) -> None:
    """400 naming the missing and the unknown fields of a /act request, if any.

    Unknown fields are refused rather than ignored: a client that sends a field this service
    does not implement (a misspelt name, an option of another version) learns it at once
    instead of having the robot act on an answer computed without it.
    """
    missing = [k for k in ("observation", "desired_goal") if k not in req]
    unknown = [k for k in req if k not in REQUEST_FIELDS]
    if not missing and not unknown:
        return
    parts = []
    if missing:
        parts.append(f"missing field(s) {missing}")
    if unknown:
        names = ", ".join(repr(k if len(k) <= 40 else k[:40] + "...") for k in unknown[:5])
        more = f" and {len(unknown) - 5} more" if len(unknown) > 5 else ""
        parts.append(f"unknown field(s) {names}{more}")
    raise RequestError(400, "; ".join(parts) + "; a request has 'observation', "
                            "'desired_goal' and optionally 'id'")


def _linger(sock: socket.socket, until: float, budget: int) -> int:
    """Shut down the sending side, then read and discard what the peer still sends, until it
    closes, ``budget`` bytes or the monotonic time ``until``; returns the bytes discarded.
    Closing with unread data would reset the connection, and a peer still sending its request
    could lose the answer it has not read yet."""
    try:
        sock.shutdown(socket.SHUT_WR)
    except OSError:
        return 0
    buf, got = bytearray(65536), 0
    while got < budget:
        left = until - time.monotonic()
        if left <= 0:
            break
        try:
            sock.settimeout(left)
            n = sock.recv_into(buf, min(len(buf), budget - got))
        except OSError:  # timeouts included
            break
        if n == 0:
            break
        got += n
    return got


class _DeadlineReader(io.RawIOBase):
    """The connection's reads: ``idle_timeout`` per read between requests; within a request
    (``deadline`` set, monotonic s) every read ends by the deadline, else ``_DeadlinePassed``."""

    def __init__(self, sock: socket.socket, idle_timeout: float):
        super().__init__()
        self._sock = sock
        self.idle_timeout = idle_timeout
        self.deadline: float | None = None

    def readable(self) -> bool:
        return True

    def readinto(self, buf) -> int:
        if self.deadline is None:
            self._sock.settimeout(self.idle_timeout)
            return self._sock.recv_into(buf)
        left = self.deadline - time.monotonic()
        if left <= 0:
            raise _DeadlinePassed
        self._sock.settimeout(left)
        try:
            return self._sock.recv_into(buf)
        except TimeoutError:
            raise _DeadlinePassed from None


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    server_version = "daddpg-policy/1"

    # -- plumbing -----------------------------------------------------------------------------

    def setup(self):
        self.timeout = self.server.limits.idle_timeout
        super().setup()
        # headers and body go out in two small writes: without TCP_NODELAY the second waits for
        # the client's delayed ACK (~40 ms per request on Linux)
        self.connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.rfile.close()  # the makefile() reader, replaced by one that keeps the deadline
        self._reader = _DeadlineReader(self.connection, self.server.limits.idle_timeout)
        self.rfile = io.BufferedReader(self._reader, 65536)
        self._deadline: float | None = None
        self._linger = False

    def finish(self):
        super().finish()
        if self._linger:
            until = max(self._deadline or 0.0, time.monotonic() + LINGER_S)
            _linger(self.connection, until, self.server.limits.max_drain)

    def handle_one_request(self):
        """``BaseHTTPRequestHandler.handle_one_request`` with the request's deadline: it starts
        at the first byte of the request line and bounds every read of the request."""
        self.requestline, self.request_version, self.command = "", "", ""
        self._reader.deadline = None
        try:
            if not self.rfile.peek(1):  # idle wait between requests; b"": the client closed
                self.close_connection = True
                return
            self._deadline = time.monotonic() + self.server.limits.request_timeout
            self._reader.deadline = self._deadline
            self.raw_requestline = self.rfile.readline(65537)
            if len(self.raw_requestline) > 65536:
                self.send_error(HTTPStatus.REQUEST_URI_TOO_LONG)
                return
            if not self.raw_requestline:
                self.close_connection = True
                return
            if not self.parse_request():  # an error has been sent
                return
            method = getattr(self, "do_" + self.command, None)
            if method is None:
                self.send_error(HTTPStatus.NOT_IMPLEMENTED,
                                f"Unsupported method ({self.command!r})")
                return
            method()
            self.wfile.flush()
        except _DeadlinePassed:
            self._timed_out()
        except (TimeoutError, ConnectionError):  # idle keep-alive connection, or client gone
            self.close_connection = True

    def log_message(self, fmt, *args):  # quiet unless asked
        if self.server.verbose:
            super().log_message(fmt, *args)

    def _send(self, status: int, payload: dict, close: bool = False):
        body = json.dumps(payload, separators=(",", ":")).encode()
        self.connection.settimeout(self.server.limits.idle_timeout)  # writes
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        if close:
            self.send_header("Connection", "close")
            self.close_connection = True
            self._linger = True
        self.end_headers()
        self.wfile.write(body)

    def _error(self, status: int, message: str, close: bool = False):
        self.server.count("errors")
        self._send(status, {"error": message, "status": status}, close=close)

    def send_error(self, code, message=None, explain=None):
        """http.server's own errors (bad request line, unsupported method, header limits) as
        JSON too."""
        try:
            text = message or HTTPStatus(code).phrase
        except ValueError:
            text = message or "error"
        try:
            self._error(int(code), str(text), close=True)
        except OSError:
            self.close_connection = True

    def _timed_out(self):
        self.server.count("timeouts")
        self.log_message("request timed out after %s s", self.server.limits.request_timeout)
        try:
            self._error(408, f"request not received within {self.server.limits.request_timeout} "
                             f"s of its first byte", close=True)
        except OSError:
            self.close_connection = True

    def handle_expect_100(self):
        """``Expect: 100-continue`` with a body over the limit: the final 413 at once, so the
        client never sends the body."""
        n = self._declared_length()
        if n is not None and n > self.server.limits.max_body:
            self.server.count("requests")
            self.send_error(413, self._too_large(n))
            return False
        self.connection.settimeout(self.server.limits.idle_timeout)
        return super().handle_expect_100()

    def _guard(self, fn):
        try:
            fn()
        except RequestError as e:
            try:
                self._error(e.status, e.message, close=e.close)
            except OSError:  # the client is gone (e.g. it sent a short body and closed)
                self.close_connection = True
        except _DeadlinePassed:
            self._timed_out()
        except (ConnectionError, TimeoutError):
            self.close_connection = True
        except Exception as e:  # noqa: BLE001 - the service must survive any request
            try:
                self._error(500, f"internal error: {type(e).__name__}: {e}", close=True)
            except OSError:
                self.close_connection = True

    # -- routes -------------------------------------------------------------------------------

    def do_GET(self):
        self.server.count("requests")
        self._guard(self._get)

    def _get(self):
        path = self.path.split("?", 1)[0]
        if path == "/health":
            self._send(200, self.server.health())
        elif path == "/info":
            self._send(200, self.server.policy.info())
        elif path == "/act":
            raise RequestError(405, "use POST for /act")
        else:
            raise RequestError(404, f"unknown path {path!r}; endpoints: POST /act, GET /health, "
                                    f"GET /info")

    def do_POST(self):
        self.server.count("requests")
        self._guard(self._post)

    def _declared_length(self) -> int | None:
        try:
            return int(self.headers.get("Content-Length", ""))
        except ValueError:
            return None

    def _too_large(self, n: int) -> str:
        return f"body of {n} bytes exceeds the limit of {self.server.limits.max_body} bytes"

    def _read_body(self) -> bytes:
        if self.headers.get("Transfer-Encoding"):
            raise RequestError(411, "chunked bodies are not accepted; send Content-Length",
                               close=True)
        length = self.headers.get("Content-Length")
        if length is None:
            raise RequestError(411, "Content-Length header required", close=True)
        n = self._declared_length()
        if n is None or n < 0:
            raise RequestError(400, f"bad Content-Length {length!r}", close=True)
        if n > self.server.limits.max_body:  # answered now; the body is drained on closing
            raise RequestError(413, self._too_large(n), close=True)
        body = self.rfile.read(n)
        if len(body) != n:
            raise RequestError(400, "body shorter than Content-Length", close=True)
        return body

    def _decode(self, body: bytes) -> dict:
        max_depth = self.server.limits.max_depth
        if json_depth_exceeds(body, max_depth):
            raise RequestError(400, f"JSON nested deeper than {max_depth} levels")
        try:
            req = json.loads(body, parse_constant=_reject_constant)
        except RecursionError:
            raise RequestError(400, "JSON nested too deeply") from None
        except (ValueError, UnicodeDecodeError) as e:
            raise RequestError(400, f"invalid JSON: {e}") from None
        if not isinstance(req, dict):
            raise RequestError(400, "request must be a JSON object with 'observation' and "
                                    "'desired_goal'")
        check_fields(req)
        return req

    def _post(self):
        body = self._read_body()  # first: an unread body would be taken for the next request
        path = self.path.split("?", 1)[0]
        if path != "/act":
            if path in ("/health", "/info"):
                raise RequestError(405, f"use GET for {path}")
            raise RequestError(404, f"unknown path {path!r}; endpoints: POST /act, GET /health, "
                                    f"GET /info")
        ctype = self.headers.get("Content-Type")
        if ctype is not None and ctype.split(";")[0].strip().lower() not in (
                "application/json", "text/json"):
            raise RequestError(415, f"Content-Type must be application/json, got {ctype!r}")
        t0 = time.perf_counter()
        req = self._decode(body)
        p = self.server.policy
        obs = parse_matrix("observation", req["observation"], p.num_arms, p.obs_size)
        goal = parse_matrix("desired_goal", req["desired_goal"], p.num_arms, p.goal_size)
        rid = req.get("id")
        if rid is not None and (isinstance(rid, bool) or not isinstance(rid, (int, str))
                                or (isinstance(rid, str) and len(rid) > 64)):
            raise RequestError(400, "'id' must be an integer or a string of at most 64 characters")
        try:
            action = p.act(obs, goal)
        except ValueError as e:
            raise RequestError(400, str(e)) from None
        out = {"action": [float(x) for x in action],
               "per_arm": action.reshape(p.num_arms, p.arm_action).tolist(),
               "latency_ms": round((time.perf_counter() - t0) * 1e3, 4)}
        if rid is not None:
            out["id"] = rid
        self._send(200, out)


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 64

    def __init__(self, addr, policy: NumpyPolicy, limits: ServiceLimits, verbose: bool):
        self.policy = policy
        self.limits = limits
        self.verbose = verbose
        self.started = time.monotonic()
        self.stats = {"requests": 0, "errors": 0, "timeouts": 0, "refused": 0}
        self.active = 0  # connections held by handler threads
        self.refusing = 0  # connections being answered 503
        self._stats_lock = threading.Lock()
        super().__init__(addr, _Handler)

    def count(self, key: str):
        with self._stats_lock:
            self.stats[key] += 1

    def health(self) -> dict:
        with self._stats_lock:
            out = {"status": "ok", **self.stats, "connections": self.active}
        out["uptime_s"] = round(time.monotonic() - self.started, 3)
        return out

    # -- the connection cap: a handler thread per admitted connection, 503 for the others --

    def process_request(self, request, client_address):
        with self._stats_lock:
            admitted = self.active < self.limits.max_connections
            if admitted:
                self.active += 1
        if not admitted:
            self._refuse(request)
            return
        try:
            super().process_request(request, client_address)  # starts the handler thread
        except BaseException:
            self._leave()
            raise

    def process_request_thread(self, request, client_address):
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._leave()

    def _leave(self):
        with self._stats_lock:
            self.active -= 1

    def _refuse(self, request):
        with self._stats_lock:
            self.stats["refused"] += 1
            self.stats["errors"] += 1
            answer = self.refusing < REFUSAL_THREADS
            if answer:
                self.refusing += 1
        if not answer:  # a flood: no thread for it
            self.shutdown_request(request)
            return
        try:
            threading.Thread(target=self._refusal, args=(request,), daemon=True,
                             name="policy-server-503").start()
        except BaseException:
            with self._stats_lock:
                self.refusing -= 1
            self.shutdown_request(request)
            raise

    def _refusal(self, request):
        """503 + close, with lingering (the client may have sent its request already)."""
        n = self.limits.max_connections
        body = json.dumps({"error": f"over capacity: {n} connections are open (the limit); "
                                    f"retry later", "status": 503}, separators=(",", ":"))
        head = (f"HTTP/1.1 503 Service Unavailable\r\nServer: {_Handler.server_version}\r\n"
                f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n"
                f"Retry-After: 1\r\nConnection: close\r\n\r\n")
        try:
            request.settimeout(1.0)
            request.sendall((head + body).encode())
            _linger(request, time.monotonic() + LINGER_S, self.limits.max_body + 65536)
        except OSError:
            pass
        finally:
            self.shutdown_request(request)
            with self._stats_lock:
                self.refusing -= 1


class PolicyServer:
    """The service around a ``NumpyPolicy``.

        server = PolicyServer(NumpyPolicy.load("policy.npz"), port=0).start()  # background thread
        ... server.url ...
        server.stop()

    ``serve_forever()`` runs in the calling thread instead (the CLI). The keyword limits are
    those of ``ServiceLimits`` (or pass ``limits=ServiceLimits(...)``).
    """

    def __init__(self, policy: NumpyPolicy, host: str = "127.0.0.1", port: int = 8000,
                 max_body: int = MAX_BODY, max_depth: int = MAX_DEPTH, verbose: bool = False,
                 request_timeout: float = REQUEST_TIMEOUT_S,
                 idle_timeout: float = IDLE_TIMEOUT_S, max_connections: int = MAX_CONNECTIONS,
                 max_drain: int = MAX_DRAIN, limits: ServiceLimits | None = None):
        self.policy = policy
        if limits is None:
            limits = ServiceLimits(max_body=int(max_body), max_depth=int(max_depth),
                                   request_timeout=float(request_timeout),
                                   idle_timeout=float(idle_timeout),
                                   max_connections=int(max_connections),
                                   max_drain=int(max_drain))
        self.limits = limits
        self.httpd = _Server((host, int(port)), policy, limits, verbose)
        self._thread: threading.Thread | None = None

    @property
    def address(self) -> tuple[str, int]:
        host, port = self.httpd.server_address[:2]
        return str(host), int(port)

    @property
    def url(self) -> str:
        host, port = self.address
        if ":" in host:
            host = f"[{host}]"
        return f"http://{host}:{port}"

    @property
    def stats(self) -> dict:
        return self.httpd.health()

    def start(self) -> PolicyServer:
        self._thread = threading.Thread(target=self.httpd.serve_forever,
                                        kwargs={"poll_interval": 0.1}, name="policy-server",
                                        daemon=True)
        self._thread.start()
        return self

    def serve_forever(self):
        self.httpd.serve_forever(poll_interval=0.2)

    def stop(self):
        self.httpd.shutdown()
        self.httpd.server_close()
        if self._thread is not None:
            self._thread.join(timeout=5)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


# -- client ------------------------------------------------------------------------------------


class PolicyClient:
    """Keep-alive HTTP client of the service (standard library only), for the robot side.

    ``act`` never raises on service trouble: it returns ``(action or None, info)`` where
    ``info`` holds ``rtt_ms`` and, on failure, ``error`` (timeout, connection refused, HTTP
    error, malformed answer). A timed-out connection is dropped (its late answer must not be
    read as the next one) and reopened on the next call. A request that finds its keep-alive
    connection closed by the service (idle timeout, restart: reset or closed before any answer)
    is sent once more on a new connection (``/act`` has no side effects).
    """

    def __init__(self, url: str, timeout: float = 1.0):
        from urllib.parse import urlsplit

        u = urlsplit(url if "://" in url else f"http://{url}")
        if u.scheme != "http" or not u.hostname:
            raise ValueError(f"policy service URL must be http://HOST:PORT, got {url!r}")
        self.host, self.port = u.hostname, int(u.port or 80)
        self.timeout = float(timeout)
        self._conn = None
        self._seq = 0

    def _connection(self):
        if self._conn is None:
            self._conn = http.client.HTTPConnection(self.host, self.port, timeout=self.timeout)
            self._conn.connect()
            self._conn.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return self._conn

    def close(self):
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def request(self, method: str, path: str, payload: dict | None = None):
        """(status, decoded JSON) of one request; raises OSError, ValueError or
        http.client.HTTPException (e.g. an answer cut short) on failure."""
        body = None if payload is None else json.dumps(payload).encode()
        headers = {"Content-Type": "application/json"} if body is not None else {}
        reused = self._conn is not None
        try:
            resp, data = self._exchange(method, path, body, headers)
        except (BrokenPipeError, ConnectionResetError):  # RemoteDisconnected included
            if not reused:
                raise
            resp, data = self._exchange(method, path, body, headers)  # a stale connection
        if resp.getheader("Connection", "").lower() == "close":
            self.close()
        return resp.status, json.loads(data)

    def _exchange(self, method, path, body, headers):
        conn = self._connection()
        try:
            conn.request(method, path, body=body, headers=headers)
            resp = conn.getresponse()
            return resp, resp.read()
        except Exception:
            self.close()
            raise

    def info(self) -> dict:
        status, out = self.request("GET", "/info")
        if status != 200:
            raise RuntimeError(f"GET /info answered {status}: {out}")
        return out

    def health(self) -> dict:
        return self.request("GET", "/health")[1]

    def act(self, observation, desired_goal):
        self._seq += 1
        payload = {"observation": np.asarray(observation, np.float64).tolist(),
                   "desired_goal": np.asarray(desired_goal, np.float64).tolist(), "id": self._seq}
        t0 = time.perf_counter()
        try:
            status, out = self.request("POST", "/act", payload)
        except (OSError, ValueError, http.client.HTTPException) as e:  # timeouts: OSErrors
            return None, {"rtt_ms": (time.perf_counter() - t0) * 1e3,
                          "error": f"{type(e).__name__}: {e}"}
        info = {"rtt_ms": (time.perf_counter() - t0) * 1e3}
        if status != 200:
            info["error"] = f"HTTP {status}: {out.get('error') if isinstance(out, dict) else out}"
            return None, info
        if not isinstance(out, dict) or out.get("id") != self._seq or "action" not in out:
            info["error"] = "malformed answer"
            return None, info
        info["server_ms"] = out.get("latency_ms")
        return out["action"], info
