"""The policy service's HTTP framing (h11) and who the client talks to: ambiguous framing gets
400 and the connection closed (nothing smuggled runs as a second request), bodies must be strict
UTF-8 JSON, the nesting check is fast; /info reports the policy file's SHA-256, the client pins
it (--policy-sha256), and the service can require a shared token (--token-file, 401 without it);
a request line and headers over 64 KiB get 431. An honest request on the same server still gets
200 (positive control).

In-process, on the checked-in export tests/data/legacy_reach/policy.npz (no JAX): ~4.5 s (the
service benchmarks: tests/test_service_bench.py)."""

from __future__ import annotations

import hashlib
import json
import os
import socket
import time

import numpy as np
import pytest

from daddpg_jax.cli import robot_client, serve
from daddpg_jax.deploy import NumpyPolicy
from daddpg_jax.deploy.client import PolicyClient, read_token
from daddpg_jax.deploy.server import PolicyServer, json_depth_exceeds

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GOOD = os.path.join(ROOT, "tests", "data", "legacy_reach", "policy.npz")
BODY = json.dumps({"observation": [[0.1] * 25] * 2, "desired_goal": [[0.2, 0.0, 0.5]] * 2})


@pytest.fixture(scope="module")
def policy():
    return NumpyPolicy.load(GOOD)


@pytest.fixture(scope="module")
def server(policy):
    with PolicyServer(policy, port=0) as srv:
        yield srv


def _exchange(server, data: bytes, wait: float = 1.0) -> bytes:
    """Sends raw bytes; everything the server answers until it closes (or ``wait`` s pass)."""
    with socket.create_connection(server.address, timeout=wait) as s:
        s.sendall(data)
        got = b""
        try:
            while True:
                c = s.recv(65536)
                if not c:
                    break
                got += c
        except (TimeoutError, ConnectionResetError):
            pass
    return got


def _post(body: bytes, *headers: bytes) -> bytes:
    return (b"POST /act HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            + b"".join(h + b"\r\n" for h in headers) + b"\r\n" + body)


def test_honest_requests_pass(server, policy):
    """Positive control: a well-framed request gets 200, twice on one connection."""
    body = BODY.encode()
    req = _post(body, b"Content-Length: %d" % len(body))
    got = _exchange(server, req + req, wait=0.5)
    assert got.count(b"HTTP/1.1 200 OK") == 2 and b"Connection: close" not in got


SMUGGLE = b"GET /info HTTP/1.1\r\nHost: x\r\n\r\n"
AMBIGUOUS = {
    # a GET /health carrying a body ran that body as a second request
    "body on GET": b"GET /health HTTP/1.1\r\nHost: x\r\nContent-Length: %d\r\n\r\n%s"
                   % (len(SMUGGLE), SMUGGLE),
    # two different Content-Lengths were accepted (the first won)
    "two lengths": _post(BODY.encode() + SMUGGLE, b"Content-Length: %d" % len(BODY),
                         b"Content-Length: %d" % (len(BODY) + len(SMUGGLE))),
    "two lengths in one header": _post(BODY.encode(), b"Content-Length: %d, 5" % len(BODY)),
    "length and chunked": _post(b"0\r\n\r\n" + SMUGGLE, b"Content-Length: 5",
                                b"Transfer-Encoding: chunked"),
    "+N length": _post(BODY.encode(), b"Content-Length: +%d" % len(BODY)),
    "1_23 length": _post(b"x" * 123, b"Content-Length: 1_23"),
    "hex length": _post(b"x" * 16, b"Content-Length: 0x10"),
    "negative length": _post(b"", b"Content-Length: -5"),
    "space in length": _post(b"x" * 12, b"Content-Length: 1 2"),
    "bad header line": _post(BODY.encode(), b"Content-Length: %d" % len(BODY), b"no colon"),
    "obs-fold": _post(BODY.encode(), b"Content-Length: %d" % len(BODY), b" folded"),
}


@pytest.mark.parametrize("name", list(AMBIGUOUS))
def test_ambiguous_framing_gets_400_and_close(server, policy, name):
    got = _exchange(server, AMBIGUOUS[name])
    assert got.startswith(b"HTTP/1.1 400 "), (name, got[:200])
    assert got.count(b"HTTP/1.1 ") == 1, (name, got)  # nothing smuggled was answered
    assert b"Connection: close" in got and b'"status":400' in got
    c = PolicyClient(server.url, timeout=5)
    assert c.act(np.zeros((2, 25)), np.zeros((2, 3)))[0] is not None  # still serving
    c.close()


@pytest.mark.parametrize("name,body", [
    ("utf-16", BODY.encode("utf-16")), ("utf-16-le", BODY.encode("utf-16-le")),
    ("bom", b"\xef\xbb\xbf" + BODY.encode()),
    ("latin-1", BODY.replace("}", ', "id": "\xe9"}').encode("latin-1")),
])
def test_bodies_that_are_not_strict_utf8_json_get_400(server, name, body):
    """UTF-16 and BOM bodies got 200 before."""
    got = _exchange(server, _post(body, b"Content-Length: %d" % len(body)), wait=0.5)
    assert got.startswith(b"HTTP/1.1 400"), (name, got[:300])


def test_nesting_check_is_fast_and_exact():
    """The nesting check walked every byte in Python (6 ms per 63 KB body)."""
    assert not json_depth_exceeds(b'{"a": [[1, 2], [3]]}', 3)
    assert json_depth_exceeds(b'{"a": [[[1]]]}', 3)
    assert not json_depth_exceeds(b'{"a": "[[[[[[[[[["}', 3)
    assert not json_depth_exceeds(b'{"a": "\\"[[[[[["}', 3)
    assert json_depth_exceeds(b'["\\\\", [[[1]]]]', 3)  # an escaped backslash ends the string
    worst = [b"[" * 64 * 1024, b'["' + b"\\[" * 32 * 1024 + b'"]',
             b"[1]," * 16 * 1024, (b'"' + b"[" * 30 + b'",') * 2000]
    for body in worst:
        t0 = time.perf_counter()
        for _ in range(20):
            json_depth_exceeds(body, 8)
        assert (time.perf_counter() - t0) / 20 < 0.002, body[:20]


# -- whom the client talks to ------------------------------------------------------------------

def test_info_reports_the_policy_files_sha256(server):
    with open(GOOD, "rb") as f:
        want = hashlib.sha256(f.read()).hexdigest()
    assert PolicyClient(server.url, timeout=5).info()["policy_sha256"] == want


def _client(url, *args, capsys):
    code = robot_client.main(["--server", url, "--fast", "--episodes", "1", *args])
    return code, capsys.readouterr()


def test_client_pins_the_sha256(server, capsys, tmp_path):
    with open(GOOD, "rb") as f:
        want = hashlib.sha256(f.read()).hexdigest()
    limits = tmp_path / "l.json"
    import tomllib

    from daddpg_jax.deploy.limits import SHIPPED

    with open(os.path.join(SHIPPED, "sim.toml"), "rb") as f:
        limits.write_text(json.dumps({**tomllib.load(f), "deadline": 2.0,
                                      "max_observation_age": 2.0}))
    code, cap = _client(server.url, "--limits", str(limits), "--policy-sha256", want.upper(),
                        capsys=capsys)
    assert code == 0, cap.err
    assert json.loads(cap.out)["policy_sha256"] == want
    other = "0" * 64
    code, cap = _client(server.url, "--policy-sha256", other, capsys=capsys)
    assert code == 2 and "is not the pinned" in cap.err.splitlines()[-1]


def test_token_required(policy, tmp_path, capsys):
    token_file = tmp_path / "token"
    token_file.write_text("s3cret-token-0123456789\n")
    token = read_token(token_file)
    with PolicyServer(policy, port=0, token=token) as srv:
        o, g = np.zeros((2, 25)), np.zeros((2, 3))
        a, info = PolicyClient(srv.url, timeout=5).act(o, g)
        assert a is None and "HTTP 401" in info["error"]
        wrong = PolicyClient(srv.url, timeout=5, token="x" * 23)
        assert wrong.act(o, g)[0] is None
        good = PolicyClient(srv.url, timeout=5, token=token)
        a, info = good.act(o, g)
        assert a is not None, info  # positive control
        assert good.info()["task"] == "reach"
        code, cap = _client(srv.url, capsys=capsys)
        assert code == 2 and "401" in cap.err.splitlines()[-1]
    for bad in ("", "short", "has space inside it", "x" * 5000):
        (tmp_path / "bad").write_text(bad)
        with pytest.raises(ValueError):
            read_token(tmp_path / "bad")
    (tmp_path / "bad").write_text("short")
    assert serve.main([GOOD, "--token-file", str(tmp_path / "bad")]) == 2
    assert "token file" in capsys.readouterr().err


def test_flood_defences(server, policy):
    """A body with more commas than any request of the policy holds is refused before the JSON
    parser builds its values; after an error answer a kept connection's next request waits
    ``error_pause`` (10 ms), so a flood of malformed requests cannot take the interpreter from
    an honest client; ~0.1 s."""
    from daddpg_jax.deploy.server import ServiceLimits

    many = b"[" + b"1," * 1000
    got = _exchange(server, _post(many, b"Content-Length: %d" % len(many)), wait=0.3)
    assert got.startswith(b"HTTP/1.1 400") and b"commas" in got
    bad, good = b"{not json", BODY.encode()
    with socket.create_connection(server.address, timeout=2) as s:
        t0 = time.perf_counter()
        s.sendall(_post(bad, b"Content-Length: %d" % len(bad))
                  + _post(good, b"Content-Length: %d" % len(good)))
        got = b""
        while got.count(b"HTTP/1.1 ") < 2 or not got.rstrip().endswith(b"}"):
            got += s.recv(65536)
        took = time.perf_counter() - t0
    assert got.startswith(b"HTTP/1.1 400") and b"HTTP/1.1 200 OK" in got
    assert took >= 0.01, took  # the second answer came after the pause
    for bad_pause in (-1.0, 11.0, float("nan")):
        with pytest.raises(ValueError):
            ServiceLimits(error_pause=bad_pause)


def _padded(head_bytes: int, body: bytes) -> bytes:
    """A /act request whose request line and headers take exactly ``head_bytes`` bytes (an
    ``X-Pad`` header fills them), then ``body``."""
    head = _post(b"", b"Content-Length: %d" % len(body), b"X-Pad: ")[:-4]  # "...X-Pad: "
    pad = head_bytes - len(head) - 4  # the header's CRLF and the blank line
    assert pad > 0
    return head + b"a" * pad + b"\r\n\r\n" + body


@pytest.mark.parametrize("head_bytes", [60 * 1024, 64 * 1024, 64 * 1024 + 1, 65 * 1024 + 1,
                                        130_000])
def test_request_head_over_64_kib_gets_431(server, policy, head_bytes):
    """A whole 130 KB head got 200: h11's limit holds only while a head is incomplete, so a head
    that arrived complete in few reads passed it. A request line and headers over MAX_HEAD
    (64 KiB) now get 431 and the connection closed; up to 64 KiB they still get 200, twice on
    one connection (pipelined: the second head is counted from its own first byte). ~0.3 s
    each (a kept connection is read for 0.3 s more)."""
    from daddpg_jax.deploy.server import MAX_HEAD

    body = BODY.encode()
    req = _padded(head_bytes, body)
    assert len(req) == head_bytes + len(body)
    if head_bytes <= MAX_HEAD:
        got = _exchange(server, req + req, wait=0.3)
        assert got.count(b"HTTP/1.1 200 OK") == 2 and b"Connection: close" not in got, got[:200]
        return
    got = _exchange(server, req, wait=2.0)
    assert got.startswith(b"HTTP/1.1 431 ") and b"Connection: close" in got, got[:300]
    assert b'"status":431' in got and b"200 OK" not in got
    # the server still serves
    ok = _exchange(server, _post(body, b"Content-Length: %d" % len(body)), wait=0.3)
    assert ok.startswith(b"HTTP/1.1 200 OK")
