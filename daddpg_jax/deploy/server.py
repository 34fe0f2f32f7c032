"""Policy service: the decision service the robot queries every control period (HTTP + JSON).

HTTP/1.1 framing by ``h11`` (a small pure-Python HTTP/1.1 implementation, no I/O of its own),
standard-library sockets (``socketserver``: one thread per connection, persistent keep-alive
connections), NumPy and ``daddpg_jax.deploy.policy``. Loopback (127.0.0.1) by default.

Endpoints
    POST /act    {"observation": [[25 floats], [25 floats]], "desired_goal": [[3], [3]],
                  "id": optional int or short string, echoed back}
                 -> 200 {"action": [8 floats], "per_arm": [[4], [4]], "latency_ms": float,
                         "id": ...}    (latency_ms: the service's own compute time)
    GET /health  -> 200 {"status": "ok", "requests": n, "errors": n, "timeouts": n,
                         "refused": n, "nonfinite": n, "connections": n, "uptime_s": s}
    GET /info    -> 200 task, algo, format version, observation layout, env settings,
                    policy_sha256 (of the policy file's bytes, as ``sha256sum`` prints it), ...

Errors get ``{"error": "...", "status": code}``: 400 malformed request line or headers,
ambiguous framing (two different Content-Lengths, Content-Length with Transfer-Encoding, a
malformed length, a body on GET), a body that is not strict UTF-8 JSON (no byte-order mark, no
NaN/Infinity), missing or unknown fields, wrong types or shapes, numbers beyond float32,
nesting deeper than ``max_depth``; 401 a token is required (``token``) and the request's
``X-Policy-Token`` header is missing or wrong; 404 unknown path; 405 wrong method for the path;
408 the request line, headers and body not received within ``request_timeout`` seconds of the
request's first byte; 411 no Content-Length, or a chunked body; 413 body over ``max_body``
bytes (answered from the header; see below); 415 a Content-Type other than JSON; 431 request
line and headers over 64 KiB (``MAX_HEAD``); 500 an unexpected exception, a policy that
produced a non-finite action (never sent), or an ONNX policy stopped at its compute-time cap
(``OnnxPolicy.max_run_s``; no action is sent); 501 a method other than GET and POST; 503
``max_connections`` connections already open. An answer to a request whose framing or headers
are refused (400 framing, 401, 408, 411, 413, 431, 500, 501, 503) closes the connection
(``Connection: close``); a well-framed request with a bad body, path, method or Content-Type
(400, 404, 405, 415) keeps it open. The server keeps serving in every case.

Limits (``ServiceLimits``): every read of a request is bounded by the request's deadline, so a
client that trickles bytes holds its thread for ``request_timeout`` seconds at most; a
keep-alive connection idle for ``idle_timeout`` seconds between requests is closed; a
connection beyond ``max_connections`` gets 503 from a small pool of refusal threads instead of
a handler thread. After any answer that closes the connection the server closes with
lingering: it sends the answer, shuts down its sending side, and reads and discards what the
client still sends (at most ``max_drain`` bytes, until the request's deadline or ``LINGER_S``
seconds, whichever is later) before closing, so that a client that sends its whole body before
reading (``http.client``, ``requests``) receives the 413 instead of a connection reset.

The client (``PolicyClient``, re-exported here) is in ``daddpg_jax.deploy.client``.
"""

from __future__ import annotations

import hmac
import json
import math
import socket
import socketserver
import sys
import threading
import time
from dataclasses import dataclass
from http import HTTPStatus

import h11
import numpy as np

from daddpg_jax.deploy import NumpyPolicy
from daddpg_jax.deploy.client import TOKEN_HEADER, PolicyClient  # noqa: F401 - re-exported
from daddpg_jax.deploy.onnx_policy import ComputeTimeout
from daddpg_jax.deploy.request_body import (  # noqa: F401 - REQUEST_FIELDS, json_depth_exceeds re-exported
    REQUEST_FIELDS,
    RequestError,
    check_fields,
    decode_body,
    json_depth_exceeds,
    parse_matrix,
)

MAX_BODY = 64 * 1024
MAX_DEPTH = 8
REQUEST_TIMEOUT_S = 5.0
IDLE_TIMEOUT_S = 10.0
MAX_CONNECTIONS = 32
MAX_DRAIN = 64 * 1024 * 1024
LINGER_S = 0.5  # least time a closing connection is drained after its answer
ERROR_PAUSE_S = 0.01  # after an error answer, a kept connection's next request waits this long
REFUSAL_THREADS = 8  # connections over the cap answered 503 at once; beyond, closed unanswered
MAX_HEAD = 64 * 1024  # request line + headers, bytes (more: 431)
SERVER_NAME = "daddpg-policy/2"
MAX_ID_CHARS = 64


@dataclass(frozen=True)
class ServiceLimits:
    """What one request or client may use (all configurable: ``PolicyServer`` and daddpg-serve).

    max_body: largest request body, bytes; max_depth: deepest JSON nesting; request_timeout: s
    from a request's first byte to the end of its body; idle_timeout: s a keep-alive connection
    may wait between requests; max_connections: open connections served at once; max_drain:
    bytes read and discarded from a connection closed after an error; error_pause: s a
    connection kept open after an error answer (400, 404, 405, 415) waits before its next
    request is read, so that a client flooding malformed requests cannot take the
    interpreter from the others (an honest client rarely gets an error).
    """

    max_body: int = MAX_BODY
    max_depth: int = MAX_DEPTH
    request_timeout: float = REQUEST_TIMEOUT_S
    idle_timeout: float = IDLE_TIMEOUT_S
    max_connections: int = MAX_CONNECTIONS
    max_drain: int = MAX_DRAIN
    error_pause: float = ERROR_PAUSE_S

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
        if not (0.0 <= float(self.error_pause) <= 10.0):
            raise ValueError(f"error_pause must be in [0, 10] s, got {self.error_pause!r}")


class _DeadlinePassed(Exception):
    """The request's deadline passed before all of it arrived."""


class _ClientGone(Exception):
    """The client closed the connection, or it stayed idle past ``idle_timeout``."""


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


def _phrase(status: int) -> str:
    try:
        return HTTPStatus(status).phrase
    except ValueError:
        return "Error"


def _answer_bytes(status: int, body: bytes, close: bool, extra=()) -> bytes:
    """An answer written without h11's state machine (answers that close the connection
    after a request h11 could not parse)."""
    head = [f"HTTP/1.1 {status} {_phrase(status)}", f"Server: {SERVER_NAME}",
            "Content-Type: application/json", f"Content-Length: {len(body)}", *extra]
    if close:
        head.append("Connection: close")
    return ("\r\n".join(head) + "\r\n\r\n").encode() + body


class _Handler(socketserver.BaseRequestHandler):
    """One connection: requests parsed by ``h11``, each bounded by its deadline (from its first
    byte to the end of its body), idle waits between requests by ``idle_timeout``."""

    # -- plumbing -----------------------------------------------------------------------------

    def setup(self):
        self.sock: socket.socket = self.request
        # an answer in one write, but the client's delayed ACK would still hold the next one
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.limits: ServiceLimits = self.server.limits
        self.conn = h11.Connection(h11.SERVER, max_incomplete_event_size=MAX_HEAD)
        self.fed = 0  # bytes of the connection handed to h11
        self.deadline: float | None = None
        self.linger = False
        self.what = "-"  # the current request's method and target, for --verbose

    def handle(self):
        try:
            while self._one_request():
                pass
        except (_ClientGone, OSError):
            pass

    def finish(self):
        if self.linger:
            until = max(self.deadline or 0.0, time.monotonic() + LINGER_S)
            _linger(self.sock, until, self.limits.max_drain)

    def _receive(self):
        """Feeds the next bytes of the connection to h11, within the request's deadline (or
        the idle timeout before a request's first byte)."""
        if self.deadline is None:
            self.sock.settimeout(self.limits.idle_timeout)
            try:
                data = self.sock.recv(65536)
            except (TimeoutError, ConnectionError):
                raise _ClientGone from None
            if not data:
                raise _ClientGone
            self.deadline = time.monotonic() + self.limits.request_timeout
        else:
            left = self.deadline - time.monotonic()
            if left <= 0:
                raise _DeadlinePassed
            self.sock.settimeout(left)
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                raise _DeadlinePassed from None
        self.fed += len(data)
        self.conn.receive_data(data)

    def _consumed(self) -> int:
        """Bytes of the connection that h11 has parsed (fed, less what it still buffers)."""
        return self.fed - len(self.conn.trailing_data[0])

    def _event(self):
        while True:
            ev = self.conn.next_event()
            if ev is not h11.NEED_DATA:
                return ev
            if self.conn.they_are_waiting_for_100_continue:
                self._write(self.conn.send(h11.InformationalResponse(status_code=100,
                                                                      headers=[])))
            self._receive()

    def _write(self, data: bytes):
        self.sock.settimeout(self.limits.idle_timeout)
        self.sock.sendall(data)

    def _log(self, status: int, what: str):
        if self.server.verbose:
            print(f"{self.client_address[0]} {what} {status}", file=sys.stderr, flush=True)

    def _send(self, status: int, payload: dict, close: bool = False, extra=()):
        body = json.dumps(payload, separators=(",", ":")).encode()
        close = close or self.conn.their_state is not h11.DONE
        headers = [("Server", SERVER_NAME), ("Content-Type", "application/json"),
                   ("Content-Length", str(len(body))), *extra]
        if close:
            headers.append(("Connection", "close"))
        try:
            data = (self.conn.send(h11.Response(status_code=status, headers=headers,
                                                reason=_phrase(status)))
                    + self.conn.send(h11.Data(data=body)) + self.conn.send(h11.EndOfMessage()))
        except h11.LocalProtocolError:  # h11 gave up on the request: write the answer as is
            data = _answer_bytes(status, body, True, [f"{k}: {v}" for k, v in extra])
            close = True
        self._write(data)
        self._log(status, self.what)
        if close:
            self.linger = True
        return close

    def _error(self, status: int, message: str, close: bool = False, extra=()) -> bool:
        self.server.count("errors")
        self.errored = True
        return self._send(status, {"error": message, "status": status}, close=close,
                          extra=extra)

    # -- one request --------------------------------------------------------------------------

    def _one_request(self) -> bool:
        """Reads, answers and finishes one request; True when the connection stays open."""
        self.deadline, self.what, self.errored = None, "-", False
        start = self._consumed()
        try:
            try:
                ev = self._event()
            except h11.RemoteProtocolError as e:  # malformed request line or headers
                if self.deadline is None:
                    raise _ClientGone from None
                self.server.count("requests")
                status = e.error_status_hint if e.error_status_hint in (400, 431, 501) else 400
                return not self._error(status, f"malformed request: {str(e)[:200]}", close=True)
            if isinstance(ev, h11.ConnectionClosed):
                return False
            self.server.count("requests")
            # h11's limit holds only while the head is incomplete: a whole head that arrived
            # in few reads passes it, so its size is checked here
            head = self._consumed() - start
            if head > MAX_HEAD:
                return not self._error(431, f"request line and headers of {head} bytes exceed "
                                            f"the limit of {MAX_HEAD} bytes", close=True)
            close = self._route(ev)
        except _DeadlinePassed:
            self.server.count("timeouts")
            try:
                self._error(408, f"request not received within {self.limits.request_timeout} "
                                 f"s of its first byte", close=True)
            except OSError:
                pass
            return False
        if close or self.conn.our_state is not h11.DONE or self.conn.their_state is not h11.DONE:
            self.linger = self.linger or close
            return False
        self.conn.start_next_cycle()
        if self.errored and self.limits.error_pause > 0:
            time.sleep(self.limits.error_pause)
        return True

    def _route(self, req: h11.Request) -> bool:
        """Answers ``req``; True when the connection must close."""
        try:
            return self._answer(req)
        except RequestError as e:
            return self._error(e.status, e.message, close=e.close, extra=e.extra)
        except h11.RemoteProtocolError as e:  # malformed body framing
            return self._error(400, f"malformed request: {str(e)[:200]}", close=True)
        except (_DeadlinePassed, _ClientGone, OSError):
            raise
        except Exception as e:  # noqa: BLE001 - the service must survive any request
            return self._error(500, f"internal error: {type(e).__name__}: {e}", close=True)

    def _read_body(self) -> bytes:
        chunks, n = [], 0
        while True:
            try:
                ev = self._event()
            except _ClientGone:
                raise RequestError(400, "body shorter than Content-Length", close=True) \
                    from None
            if isinstance(ev, h11.Data):
                n += len(ev.data)
                if n > self.limits.max_body:  # h11 holds the body to its Content-Length
                    raise RequestError(413, self._too_large(n), close=True)
                chunks.append(bytes(ev.data))
            elif isinstance(ev, h11.EndOfMessage):
                return b"".join(chunks)
            else:  # ConnectionClosed
                raise RequestError(400, "body shorter than Content-Length", close=True)

    def _too_large(self, n: int) -> str:
        return f"body of {n} bytes exceeds the limit of {self.limits.max_body} bytes"

    def _framing(self, req: h11.Request) -> int | None:
        """The declared body length (None: no Content-Length); RequestError for a request whose
        framing is ambiguous or refused."""
        lengths = [v for k, v in req.headers if k == b"content-length"]
        chunked = any(k == b"transfer-encoding" for k, _ in req.headers)
        if chunked and lengths:
            raise RequestError(400, "both Content-Length and Transfer-Encoding: ambiguous "
                                    "framing", close=True)
        if chunked:
            raise RequestError(411, "chunked bodies are not accepted; send Content-Length",
                               close=True)
        return int(lengths[0]) if lengths else None

    def _check_token(self, req: h11.Request):
        token = self.server.token
        if token is None:
            return
        given = [v for k, v in req.headers if k == TOKEN_HEADER.lower().encode()]
        if len(given) != 1 or not hmac.compare_digest(given[0], token):
            raise RequestError(401, f"missing or wrong {TOKEN_HEADER} header", close=True)

    def _answer(self, req: h11.Request) -> bool:
        method = req.method.decode("ascii", "replace")
        target = req.target.decode("ascii", "replace")
        self.what = f"{method} {target[:80]}"
        path = target.split("?", 1)[0]
        n = self._framing(req)
        if method not in ("GET", "POST"):
            raise RequestError(501, f"Unsupported method ({method!r})", close=True)
        self._check_token(req)
        if method == "GET":
            if n:  # a body on a method that takes none
                raise RequestError(400, "GET requests take no body", close=True)
            self._read_body()
            return self._get(path)
        if n is None:
            raise RequestError(411, "Content-Length header required", close=True)
        if n > self.limits.max_body:  # answered now; the body is drained on closing
            raise RequestError(413, self._too_large(n), close=True)
        body = self._read_body()  # first: an unread body would be taken for the next request
        return self._post(path, req, body)

    def _get(self, path: str) -> bool:
        if path == "/health":
            return self._send(200, self.server.health())
        if path == "/info":
            return self._send(200, self.server.policy.info())
        if path == "/act":
            raise RequestError(405, "use POST for /act")
        raise RequestError(404, f"unknown path {path!r}; endpoints: POST /act, GET /health, "
                                f"GET /info")

    def _post(self, path: str, req: h11.Request, body: bytes) -> bool:
        if path != "/act":
            if path in ("/health", "/info"):
                raise RequestError(405, f"use GET for {path}")
            raise RequestError(404, f"unknown path {path!r}; endpoints: POST /act, GET /health, "
                                    f"GET /info")
        ctype = [v for k, v in req.headers if k == b"content-type"]
        if ctype and ctype[0].decode("latin-1").split(";")[0].strip().lower() not in (
                "application/json", "text/json"):
            raise RequestError(415, f"Content-Type must be application/json, got "
                                    f"{ctype[0].decode('latin-1')!r}")
        t0 = time.perf_counter()
        p = self.server.policy
        # a request holds num_arms * (obs + goal) numbers and an id of <= 64 characters: a body
        # with more commas cannot be one, and is refused before the JSON parser (which holds the
        # interpreter lock while it builds every value) sees it
        most = p.num_arms * (p.obs_size + p.goal_size) + MAX_ID_CHARS + 8
        if body.count(b",") > most:
            raise RequestError(400, f"more than {most} commas: not a request of this policy")
        req_json = decode_body(body, self.limits.max_depth)
        if not isinstance(req_json, dict):
            raise RequestError(400, "request must be a JSON object with 'observation' and "
                                    "'desired_goal'")
        check_fields(req_json)
        obs = parse_matrix("observation", req_json["observation"], p.num_arms, p.obs_size)
        goal = parse_matrix("desired_goal", req_json["desired_goal"], p.num_arms, p.goal_size)
        rid = req_json.get("id")
        if rid is not None and (isinstance(rid, bool) or not isinstance(rid, (int, str))
                                or (isinstance(rid, str) and len(rid) > MAX_ID_CHARS)
                                or (isinstance(rid, int) and abs(rid) >= 2 ** 53)):
            raise RequestError(400, f"'id' must be an integer (|id| < 2^53) or a string of at "
                                    f"most {MAX_ID_CHARS} characters")
        try:
            action = np.asarray(p.act(obs, goal), np.float32)
        except ValueError as e:
            raise RequestError(400, str(e)) from None
        except ComputeTimeout as e:  # an ONNX graph stopped at its compute cap
            raise RequestError(500, f"{e}; no action is sent", close=True) from None
        if action.shape != (p.num_arms * p.arm_action,) or not np.all(np.isfinite(action)):
            self.server.count("nonfinite")
            raise RequestError(500, "the policy produced a non-finite or malformed action; "
                                    "none is sent")
        out = {"action": [float(x) for x in action],
               "per_arm": action.reshape(p.num_arms, p.arm_action).tolist(),
               "latency_ms": round((time.perf_counter() - t0) * 1e3, 4)}
        if rid is not None:
            out["id"] = rid
        return self._send(200, out)


class _Server(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 64

    def __init__(self, addr, policy: NumpyPolicy, limits: ServiceLimits, verbose: bool,
                 token: bytes | None = None):
        self.policy = policy
        self.limits = limits
        self.verbose = verbose
        self.token = token
        self.started = time.monotonic()
        self.stats = {"requests": 0, "errors": 0, "timeouts": 0, "refused": 0, "nonfinite": 0}
        if ":" in addr[0]:
            self.address_family = socket.AF_INET6
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
        data = _answer_bytes(503, body.encode(), True, ["Retry-After: 1"])
        try:
            request.settimeout(1.0)
            request.sendall(data)
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
                 max_drain: int = MAX_DRAIN, limits: ServiceLimits | None = None,
                 token: str | None = None):
        self.policy = policy
        if limits is None:
            limits = ServiceLimits(max_body=int(max_body), max_depth=int(max_depth),
                                   request_timeout=float(request_timeout),
                                   idle_timeout=float(idle_timeout),
                                   max_connections=int(max_connections),
                                   max_drain=int(max_drain))
        self.limits = limits
        if token is not None and not token:
            raise ValueError("the token must not be empty")
        self.httpd = _Server((host, int(port)), policy, limits, verbose,
                             None if token is None else token.encode())
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
