"""Client of the policy service, for the robot side: one monotonic deadline per request.

The HTTP/1.1 framing is parsed by ``h11`` (a small pure-Python library, no I/O of its own).
Each request gets one deadline, ``timeout`` seconds after it starts, that bounds everything
it does: connecting, sending, the answer's headers and its body. No single read may outlast it
(a service that trickles its answer a byte at a time is cut at the deadline, not after each
read), and an answer larger than ``max_answer`` bytes (headers and body) is refused after
reading at most that many bytes. A request that fails in any way closes its connection (its
late answer must not be read as the next one); the next request opens a new one.
"""

from __future__ import annotations

import json
import socket
import time
from urllib.parse import urlsplit

import h11
import numpy as np

MAX_ANSWER = 64 * 1024
"""Largest answer the client reads (headers + body, bytes); the service's answers are < 2 KiB."""
TOKEN_HEADER = "X-Policy-Token"
"""Header that carries the shared token (``daddpg-serve --token-file``)."""


class AnswerError(ValueError):
    """The service's answer is malformed: bad HTTP framing, over ``max_answer`` bytes, not
    strict UTF-8 JSON."""


class DeadlineExceeded(TimeoutError):
    """The request's deadline passed before its answer was complete."""


class _Stale(Exception):
    """A reused keep-alive connection was found closed before any byte of the answer."""


def _reject_constant(name):
    raise ValueError(f"{name} is not valid JSON")


def decode_json(data: bytes):
    """Strict JSON: UTF-8 without a byte-order mark, no NaN/Infinity; AnswerError otherwise."""
    if data[:3] == b"\xef\xbb\xbf":
        raise AnswerError("JSON with a byte-order mark")
    try:
        return json.loads(data.decode("utf-8"), parse_constant=_reject_constant)
    except RecursionError:
        raise AnswerError("JSON nested too deeply") from None
    except (UnicodeDecodeError, ValueError) as e:
        raise AnswerError(f"not strict UTF-8 JSON: {e}") from None


class PolicyClient:
    """Keep-alive HTTP client of the policy service.

    ``act`` never raises on service trouble: it returns ``(action or None, info)`` where
    ``info`` holds ``rtt_ms`` and, on failure, ``error`` (deadline, connection refused, HTTP
    error, malformed answer). A request that finds its reused keep-alive connection closed by
    the service (idle timeout, restart) before any byte of the answer is sent once more on a new
    connection, within the same deadline (``/act`` has no side effects).

    url: ``http://HOST:PORT``; timeout: each request's deadline, s; max_answer: bytes;
    token: the shared token sent in ``X-Policy-Token`` (None: none sent).
    """

    def __init__(self, url: str, timeout: float = 1.0, max_answer: int = MAX_ANSWER,
                 token: str | None = None):
        u = urlsplit(url if "://" in url else f"http://{url}")
        try:
            port = int(u.port or 80)
        except ValueError:
            port = -1
        if u.scheme != "http" or not u.hostname or port < 1:
            raise ValueError(f"policy service URL must be http://HOST:PORT, got {url!r}")
        self.host, self.port = u.hostname, port
        self.timeout = float(timeout)
        if not self.timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        self.max_answer = int(max_answer)
        self.token = token
        self._sock: socket.socket | None = None
        self._conn: h11.Connection | None = None
        self._seq = 0

    # -- connection ---------------------------------------------------------------------------

    def close(self):
        if self._sock is not None:
            try:
                self._sock.close()
            except OSError:
                pass
        self._sock, self._conn = None, None

    @staticmethod
    def _left(deadline: float) -> float:
        left = deadline - time.monotonic()
        if left <= 0:
            raise DeadlineExceeded("timed out: the request's deadline passed")
        return left

    def _connect(self, deadline: float):
        sock = socket.create_connection((self.host, self.port), timeout=self._left(deadline))
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock, self._conn = sock, h11.Connection(h11.CLIENT)

    # -- one request --------------------------------------------------------------------------

    def request(self, method: str, path: str, payload: dict | None = None,
                timeout: float | None = None):
        """(status, decoded JSON) of one request within one deadline (``timeout`` s, default
        the client's). Raises DeadlineExceeded (a TimeoutError), OSError or AnswerError (a
        ValueError) on failure; the connection is then closed."""
        deadline = time.monotonic() + (self.timeout if timeout is None else float(timeout))
        body = b"" if payload is None else json.dumps(payload).encode()
        reused = self._sock is not None
        try:
            try:
                return self._exchange(method, path, body, payload is not None, deadline)
            except _Stale:
                if not reused:
                    raise ConnectionResetError("connection closed before the answer") from None
                self.close()
                return self._exchange(method, path, body, payload is not None, deadline)
        except _Stale:
            self.close()
            raise ConnectionResetError("connection closed before the answer") from None
        except TimeoutError as e:  # socket timeouts included: they are the deadline's
            self.close()
            if isinstance(e, DeadlineExceeded):
                raise
            raise DeadlineExceeded("timed out: the request's deadline passed") from None
        except BaseException:
            self.close()
            raise

    def _exchange(self, method, path, body: bytes, has_body: bool, deadline: float):
        if self._sock is None:
            self._connect(deadline)
        conn = self._conn
        headers = [("Host", f"{self.host}:{self.port}")]
        if has_body:
            headers += [("Content-Type", "application/json"),
                        ("Content-Length", str(len(body)))]
        if self.token is not None:
            headers.append((TOKEN_HEADER, self.token))
        try:
            data = conn.send(h11.Request(method=method, target=path, headers=headers))
            if has_body:
                data += conn.send(h11.Data(data=body))
            data += conn.send(h11.EndOfMessage())
        except h11.LocalProtocolError as e:
            raise AnswerError(f"cannot send the request: {e}") from None
        sock = self._sock
        try:
            sock.settimeout(self._left(deadline))
            sock.sendall(data)  # one timeout for the whole send
        except (BrokenPipeError, ConnectionResetError):
            raise _Stale from None
        status, chunks, got = None, [], 0
        while True:
            try:
                event = conn.next_event()
            except h11.RemoteProtocolError as e:
                if got == 0:
                    raise _Stale from None
                raise AnswerError(f"malformed HTTP answer: {e}") from None
            if event is h11.NEED_DATA:
                sock.settimeout(self._left(deadline))
                try:
                    chunk = sock.recv(min(65536, self.max_answer - got + 1))
                except ConnectionResetError:
                    if got == 0:
                        raise _Stale from None
                    raise
                got += len(chunk)
                if got > self.max_answer:
                    raise AnswerError(f"answer larger than {self.max_answer} bytes")
                conn.receive_data(chunk)
            elif isinstance(event, h11.InformationalResponse):
                continue
            elif isinstance(event, h11.Response):
                status = event.status_code
            elif isinstance(event, h11.Data):
                chunks.append(bytes(event.data))
            elif isinstance(event, h11.EndOfMessage):
                break
            elif isinstance(event, h11.ConnectionClosed):
                if got == 0:
                    raise _Stale
                raise AnswerError("connection closed before the answer was complete")
        if conn.our_state is h11.MUST_CLOSE or conn.their_state is h11.MUST_CLOSE:
            self.close()
        else:
            try:
                conn.start_next_cycle()
            except h11.LocalProtocolError:
                self.close()
        return status, decode_json(b"".join(chunks))

    # -- endpoints ----------------------------------------------------------------------------

    def info(self, timeout: float | None = None) -> dict:
        status, out = self.request("GET", "/info", timeout=timeout)
        if status != 200 or not isinstance(out, dict):
            raise RuntimeError(f"GET /info answered {status}: {out}")
        return out

    def health(self, timeout: float | None = None) -> dict:
        return self.request("GET", "/health", timeout=timeout)[1]

    def act(self, observation, desired_goal):
        """(action or None, info) for one control period; never raises on service trouble.
        ``info``: ``rtt_ms``, ``server_ms`` (the service's own compute time) and, on failure,
        ``error``."""
        self._seq += 1
        payload = {"observation": np.asarray(observation, np.float64).tolist(),
                   "desired_goal": np.asarray(desired_goal, np.float64).tolist(), "id": self._seq}
        t0 = time.perf_counter()
        try:
            status, out = self.request("POST", "/act", payload)
        except (OSError, ValueError) as e:  # deadlines are OSErrors (TimeoutError)
            return None, {"rtt_ms": (time.perf_counter() - t0) * 1e3,
                          "error": f"{type(e).__name__}: {e}"}
        info = {"rtt_ms": (time.perf_counter() - t0) * 1e3}
        if status != 200:
            msg = out.get("error") if isinstance(out, dict) else out
            info["error"] = f"HTTP {status}: {str(msg)[:200]}"
            return None, info
        if not isinstance(out, dict) or out.get("id") != self._seq or "action" not in out:
            info["error"] = "malformed answer"
            return None, info
        ms = out.get("latency_ms")
        info["server_ms"] = ms if isinstance(ms, (int, float)) and not isinstance(ms, bool) \
            else None
        return out["action"], info


def read_token(path) -> str:
    """The shared token in a file: its first line without surrounding whitespace, 16 to 4096
    visible ASCII characters. ValueError (one line) otherwise."""
    try:
        with open(path, "rb") as f:
            raw = f.read(8193)
    except OSError as e:
        raise ValueError(f"cannot read token file {str(path)!r}: {e.strerror or e}") from None
    lines = raw.splitlines()
    token = lines[0].strip() if lines else b""
    if not 16 <= len(token) <= 4096 or any(c < 0x21 or c > 0x7E for c in token):
        raise ValueError(f"token file {str(path)!r} must hold one line of 16 to 4096 visible "
                         f"ASCII characters")
    return token.decode("ascii")
