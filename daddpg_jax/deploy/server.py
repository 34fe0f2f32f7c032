"""Policy service: the decision service the robot queries every control period (HTTP + JSON).

Standard library only (``http.server.ThreadingHTTPServer``) plus NumPy and
``daddpg_jax.deploy.policy``: no web framework to install on the robot computer, one thread per
connection, persistent (HTTP/1.1 keep-alive) connections. Loopback (127.0.0.1) by default.

Endpoints
    POST /act    {"observation": [[25 floats], [25 floats]], "desired_goal": [[3], [3]],
                  "id": optional int or short string, echoed back}
                 -> 200 {"action": [8 floats], "per_arm": [[4], [4]], "latency_ms": float,
                         "id": ...}
    GET /health  -> 200 {"status": "ok", "requests": n, "errors": n, "uptime_s": s}
    GET /info    -> 200 task, algo, format version, observation layout, env settings, ...

Malformed requests get a 4xx and ``{"error": "...", "status": code}``: 400 bad JSON, missing
fields, wrong types or shapes, NaN/inf, nesting deeper than ``max_depth``; 404 unknown path;
405 wrong method; 411 no Content-Length; 413 body over ``max_body`` bytes (64 KiB; the
connection is then closed without reading it); 415 a Content-Type other than JSON. An
unexpected exception answers 500; the server keeps serving in every case.
"""

from __future__ import annotations

import json
import math
import socket
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import numpy as np

from daddpg_jax.deploy import NumpyPolicy

MAX_BODY = 64 * 1024
MAX_DEPTH = 8


class RequestError(Exception):
    def __init__(self, status: int, message: str, close: bool = False):
        super().__init__(message)
        self.status = status
        self.message = message
        self.close = close


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


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    server_version = "daddpg-policy/1"
    timeout = 10.0  # seconds a client may stall mid-request before its connection is dropped

    # -- plumbing -----------------------------------------------------------------------------

    def setup(self):
        super().setup()
        # headers and body go out in two small writes: without TCP_NODELAY the second waits for
        # the client's delayed ACK (~40 ms per request on Linux)
        self.connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def log_message(self, fmt, *args):  # quiet unless asked
        if self.server.verbose:
            super().log_message(fmt, *args)

    def _send(self, status: int, payload: dict, close: bool = False):
        body = json.dumps(payload, separators=(",", ":")).encode()
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        if close:
            self.send_header("Connection", "close")
            self.close_connection = True
        self.end_headers()
        self.wfile.write(body)

    def _error(self, status: int, message: str, close: bool = False):
        self.server.count("errors")
        self._send(status, {"error": message, "status": status}, close=close)

    def send_error(self, code, message=None, explain=None):
        """http.server's own errors (bad request line, unsupported method, header limits) as
        JSON too."""
        try:
            from http import HTTPStatus

            text = message or HTTPStatus(code).phrase
        except ValueError:
            text = message or "error"
        try:
            self._error(int(code), str(text), close=True)
        except OSError:
            self.close_connection = True

    def _guard(self, fn):
        try:
            fn()
        except RequestError as e:
            try:
                self._error(e.status, e.message, close=e.close)
            except OSError:  # the client is gone (e.g. it sent a short body and closed)
                self.close_connection = True
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
            s = self.server
            self._send(200, {"status": "ok", "requests": s.stats["requests"],
                             "errors": s.stats["errors"],
                             "uptime_s": round(time.monotonic() - s.started, 3)})
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

    def _read_body(self) -> bytes:
        if self.headers.get("Transfer-Encoding"):
            raise RequestError(411, "chunked bodies are not accepted; send Content-Length",
                               close=True)
        length = self.headers.get("Content-Length")
        if length is None:
            raise RequestError(411, "Content-Length header required", close=True)
        try:
            n = int(length)
        except ValueError:
            raise RequestError(400, f"bad Content-Length {length!r}", close=True) from None
        if n < 0:
            raise RequestError(400, f"bad Content-Length {length!r}", close=True)
        if n > self.server.max_body:
            raise RequestError(413, f"body of {n} bytes exceeds the limit of "
                                    f"{self.server.max_body} bytes", close=True)
        body = self.rfile.read(n)
        if len(body) != n:
            raise RequestError(400, "body shorter than Content-Length", close=True)
        return body

    def _post(self):
        path = self.path.split("?", 1)[0]
        if path != "/act":
            if path in ("/health", "/info"):
                raise RequestError(405, f"use GET for {path}", close=True)
            raise RequestError(404, f"unknown path {path!r}; endpoints: POST /act, GET /health, "
                                    f"GET /info", close=True)
        ctype = self.headers.get("Content-Type")
        body = self._read_body()
        if ctype is not None and ctype.split(";")[0].strip().lower() not in (
                "application/json", "text/json"):
            raise RequestError(415, f"Content-Type must be application/json, got {ctype!r}")
        t0 = time.perf_counter()
        if json_depth_exceeds(body, self.server.max_depth):
            raise RequestError(400, f"JSON nested deeper than {self.server.max_depth} levels")
        try:
            req = json.loads(body, parse_constant=_reject_constant)
        except RecursionError:
            raise RequestError(400, "JSON nested too deeply") from None
        except (ValueError, UnicodeDecodeError) as e:
            raise RequestError(400, f"invalid JSON: {e}") from None
        if not isinstance(req, dict):
            raise RequestError(400, "request must be a JSON object with 'observation' and "
                                    "'desired_goal'")
        missing = [k for k in ("observation", "desired_goal") if k not in req]
        if missing:
            raise RequestError(400, f"missing field(s) {missing}")
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

    def __init__(self, addr, policy: NumpyPolicy, max_body: int, max_depth: int, verbose: bool):
        self.policy = policy
        self.max_body = int(max_body)
        self.max_depth = int(max_depth)
        self.verbose = verbose
        self.started = time.monotonic()
        self.stats = {"requests": 0, "errors": 0}
        self._stats_lock = threading.Lock()
        super().__init__(addr, _Handler)

    def count(self, key: str):
        with self._stats_lock:
            self.stats[key] += 1


class PolicyServer:
    """The service around a ``NumpyPolicy``.

        server = PolicyServer(NumpyPolicy.load("policy.npz"), port=0).start()  # background thread
        ... server.url ...
        server.stop()

    ``serve_forever()`` runs in the calling thread instead (the CLI).
    """

    def __init__(self, policy: NumpyPolicy, host: str = "127.0.0.1", port: int = 8000,
                 max_body: int = MAX_BODY, max_depth: int = MAX_DEPTH, verbose: bool = False):
        self.policy = policy
        self.httpd = _Server((host, int(port)), policy, max_body, max_depth, verbose)
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
        return dict(self.httpd.stats)

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
    read as the next one) and reopened on the next call.
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
        import http.client

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
        """(status, decoded JSON) of one request; raises OSError/ValueError on failure."""
        conn = self._connection()
        body = None if payload is None else json.dumps(payload).encode()
        headers = {"Content-Type": "application/json"} if body is not None else {}
        try:
            conn.request(method, path, body=body, headers=headers)
            resp = conn.getresponse()
            data = resp.read()
        except Exception:
            self.close()
            raise
        if resp.getheader("Connection", "").lower() == "close":
            self.close()
        return resp.status, json.loads(data)

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
        except (OSError, ValueError) as e:  # timeouts are OSErrors
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
