"""Policy service: happy path, every malformed-input class, liveness after them, concurrency,
and the limits: oversized bodies (413 reaches a client that sends the whole body), the request
deadline (408 for a trickling client), the connection cap (503), unknown fields (400)."""

from __future__ import annotations

import http.client
import json
import socket
import threading
import time

import jax
import numpy as np
import pytest

import mjx_envs
from daddpg_jax.algo.config import TrainConfig
from daddpg_jax.algo.train import make_train_fns
from daddpg_jax.deploy import FORMAT_VERSION, NumpyPolicy
from daddpg_jax.deploy.server import (
    PolicyClient,
    PolicyServer,
    ServiceLimits,
    json_depth_exceeds,
)
from daddpg_jax.running.export import export_state
from mjx_envs import observation as obs_lib


@pytest.fixture(scope="module")
def policy(tmp_path_factory):
    env = mjx_envs.make("reach", physics="c")
    cfg = TrainConfig(hidden=(32, 32), num_envs=2, n_cycles=1, n_batches=1, batch_size=8,
                      buffer_size=200, n_test_episodes=2)
    fns = make_train_fns(env, cfg)
    path = export_state(fns.init(jax.random.PRNGKey(0)), cfg, env,
                        str(tmp_path_factory.mktemp("srv") / "p.npz"))
    return NumpyPolicy.load(path)


@pytest.fixture(scope="module")
def server(policy):
    srv = PolicyServer(policy, port=0).start()
    yield srv
    srv.stop()


def _inputs(seed=0):
    rng = np.random.default_rng(seed)
    return (rng.normal(0, 0.3, (2, 25)).astype(np.float32),
            rng.uniform(0.1, 0.5, (2, 3)).astype(np.float32))


def _request(server, method, path, body=None, headers=None):
    host, port = server.address
    conn = http.client.HTTPConnection(host, port, timeout=10)
    try:
        if isinstance(body, (dict, list)):
            body = json.dumps(body)
        hdrs = {"Content-Type": "application/json"} if body is not None else {}
        hdrs.update(headers or {})
        conn.request(method, path, body=body, headers=hdrs)
        r = conn.getresponse()
        return r.status, json.loads(r.read())
    finally:
        conn.close()


def _raw(server, data: bytes) -> bytes:
    """Sends raw bytes and returns the whole answer (the server closes after an error)."""
    with socket.create_connection(server.address, timeout=10) as s:
        s.sendall(data)
        chunks = []
        while True:
            try:
                c = s.recv(65536)
            except ConnectionResetError:
                break
            if not c:
                break
            chunks.append(c)
            if b"\r\n\r\n" in b"".join(chunks):
                head, _, rest = b"".join(chunks).partition(b"\r\n\r\n")
                n = [int(line.split(b":")[1]) for line in head.split(b"\r\n")
                     if line.lower().startswith(b"content-length")]
                if n and len(rest) >= n[0]:
                    break
        return b"".join(chunks)


def _assert_alive(server, policy):
    status, out = _request(server, "GET", "/health")
    assert status == 200 and out["status"] == "ok"
    o, g = _inputs(5)
    status, out = _request(server, "POST", "/act", {"observation": o.tolist(),
                                                    "desired_goal": g.tolist()})
    assert status == 200
    np.testing.assert_allclose(out["action"], policy.act(o, g), atol=1e-7)


def test_act_health_info(server, policy):
    o, g = _inputs()
    status, out = _request(server, "POST", "/act", {"observation": o.tolist(),
                                                    "desired_goal": g.tolist(), "id": 17})
    assert status == 200
    expected = policy.act(o, g)
    assert len(out["action"]) == 8 and out["id"] == 17
    np.testing.assert_array_equal(np.asarray(out["action"], np.float32), expected)
    np.testing.assert_array_equal(np.asarray(out["per_arm"], np.float32), expected.reshape(2, 4))
    assert out["latency_ms"] >= 0.0
    status, info = _request(server, "GET", "/info")
    assert status == 200
    assert info["task"] == "reach" and info["algo"] == "daddpg"
    assert info["format_version"] == FORMAT_VERSION
    assert info["obs_layout"] == {k: list(v) for k, v in obs_lib.obs_layout().items()}
    assert info["env"]["dt"] == pytest.approx(0.04)
    status, health = _request(server, "GET", "/health")
    assert status == 200 and health["status"] == "ok" and health["requests"] >= 2
    # integers are numbers too
    status, out = _request(server, "POST", "/act", {"observation": [[0] * 25] * 2,
                                                    "desired_goal": [[0, 0, 1]] * 2})
    assert status == 200


def test_client_keeps_connection_and_matches(server, policy):
    c = PolicyClient(server.url, timeout=5)
    for k in range(20):
        o, g = _inputs(k)
        a, info = c.act(o, g)
        assert "error" not in info
        np.testing.assert_array_equal(np.asarray(a, np.float32), policy.act(o, g))
    sock = c._sock
    c.act(*_inputs(99))
    assert c._sock is sock  # one keep-alive connection
    assert c.info()["task"] == "reach"
    c.close()


GOOD_O, GOOD_G = [[0.1] * 25] * 2, [[0.2, 0.0, 0.5]] * 2

MALFORMED_JSON = [
    ("bad json", b"{not json"),
    ("truncated", b'{"observation": [[1, 2'),
    ("not an object", b"[1, 2, 3]"),
    ("a string", b'"hello"'),
    ("empty body", b""),
    ("bad utf-8", b'{"observation": "\xff\xfe"}'),
    ("NaN token", json.dumps({"observation": GOOD_O, "desired_goal": GOOD_G}).replace(
        "0.1", "NaN", 1).encode()),
    ("Infinity token", json.dumps({"observation": GOOD_O, "desired_goal": GOOD_G}).replace(
        "0.2", "-Infinity", 1).encode()),
    ("huge number", json.dumps({"observation": GOOD_O, "desired_goal": GOOD_G}).replace(
        "0.2", "1e999", 1).encode()),
    ("deep nesting", b"[" * 5000 + b"]" * 5000),
    ("deep nesting in object", b'{"observation": ' + b"[" * 30 + b"]" * 30 + b"}"),
]

MALFORMED_FIELDS = [
    ("missing observation", {"desired_goal": GOOD_G}),
    ("missing goal", {"observation": GOOD_O}),
    ("one arm", {"observation": GOOD_O[:1], "desired_goal": GOOD_G}),
    ("short row", {"observation": [[0.1] * 24] * 2, "desired_goal": GOOD_G}),
    ("long goal", {"observation": GOOD_O, "desired_goal": [[0.1] * 4] * 2}),
    ("flat", {"observation": [0.1] * 50, "desired_goal": GOOD_G}),
    ("string entry", {"observation": [["x"] * 25] * 2, "desired_goal": GOOD_G}),
    ("null entry", {"observation": GOOD_O, "desired_goal": [[None, 0, 0]] * 2}),
    ("bool entry", {"observation": GOOD_O, "desired_goal": [[True, 0, 0]] * 2}),
    ("nested entry", {"observation": GOOD_O, "desired_goal": [[[0.1], 0, 0]] * 2}),
    ("object field", {"observation": {"a": 1}, "desired_goal": GOOD_G}),
    ("bad id", {"observation": GOOD_O, "desired_goal": GOOD_G, "id": [1]}),
    ("long id", {"observation": GOOD_O, "desired_goal": GOOD_G, "id": "x" * 65}),
    ("unknown field", {"observation": GOOD_O, "desired_goal": GOOD_G, "deterministic": True}),
    ("misspelt field", {"observation": GOOD_O, "desired_goals": GOOD_G}),
]


@pytest.mark.parametrize("name,body", MALFORMED_JSON, ids=[m[0] for m in MALFORMED_JSON])
def test_malformed_json_gets_400(server, policy, name, body):
    status, out = _request(server, "POST", "/act", body)
    assert status == 400, (name, out)
    assert out["status"] == 400 and isinstance(out["error"], str) and out["error"]
    _assert_alive(server, policy)


@pytest.mark.parametrize("name,payload", MALFORMED_FIELDS, ids=[m[0] for m in MALFORMED_FIELDS])
def test_malformed_fields_get_400(server, policy, name, payload):
    status, out = _request(server, "POST", "/act", payload)
    assert status == 400, (name, out)
    assert out["error"]
    _assert_alive(server, policy)


def test_error_messages_say_what_is_wrong(server):
    _, out = _request(server, "POST", "/act", {"observation": GOOD_O})
    assert "desired_goal" in out["error"]
    _, out = _request(server, "POST", "/act",
                      {"observation": [[0.1] * 24] * 2, "desired_goal": GOOD_G})
    assert "observation" in out["error"] and "25" in out["error"]


def test_http_level_errors(server, policy):
    status, out = _request(server, "POST", "/act", b"x" * (64 * 1024 + 1))
    assert status == 413 and "exceeds" in out["error"]
    status, _ = _request(server, "POST", "/act", json.dumps({"observation": GOOD_O,
                                                             "desired_goal": GOOD_G}),
                         headers={"Content-Type": "text/plain"})
    assert status == 415
    assert _request(server, "GET", "/nowhere")[0] == 404
    assert _request(server, "POST", "/nowhere", {"a": 1})[0] == 404
    assert _request(server, "GET", "/act")[0] == 405
    assert _request(server, "POST", "/health", {"a": 1})[0] == 405
    # no Content-Length
    ans = _raw(server, b"POST /act HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n\r\n")
    assert ans.startswith(b"HTTP/1.1 411")
    # a huge declared length is refused before reading anything
    ans = _raw(server, b"POST /act HTTP/1.1\r\nHost: x\r\nContent-Length: 999999999\r\n\r\n{")
    assert ans.startswith(b"HTTP/1.1 413")
    ans = _raw(server, b"POST /act HTTP/1.1\r\nHost: x\r\nContent-Length: -5\r\n\r\n")
    assert ans.startswith(b"HTTP/1.1 400")
    ans = _raw(server, b"garbage\r\n\r\n")
    assert b'"status":400' in ans
    ans = _raw(server, b"DELETE /act HTTP/1.1\r\nHost: x\r\n\r\n")
    assert ans.startswith(b"HTTP/1.1 501") and b'"error"' in ans
    _assert_alive(server, policy)


def test_stalled_client_does_not_block_others(server, policy):
    s = socket.create_connection(server.address, timeout=10)
    try:
        s.sendall(b"POST /act HTTP/1.1\r\nHost: x\r\nContent-Length: 500\r\n\r\n{\"obs")
        t0 = time.perf_counter()
        _assert_alive(server, policy)
        assert time.perf_counter() - t0 < 5.0
    finally:
        s.close()


def test_concurrent_clients(server, policy):
    n_threads, n_req = 8, 25
    failures = []

    def worker(i):
        c = PolicyClient(server.url, timeout=10)
        try:
            for k in range(n_req):
                o, g = _inputs(1000 * i + k)
                a, info = c.act(o, g)
                if a is None or not np.array_equal(np.asarray(a, np.float32), policy.act(o, g)):
                    failures.append((i, k, info))
        finally:
            c.close()

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(n_threads)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert not failures, failures[:3]
    _assert_alive(server, policy)


def test_json_depth_scan():
    assert not json_depth_exceeds(b'{"a": [[1, 2], [3]]}', 3)
    assert json_depth_exceeds(b'{"a": [[[1]]]}', 3)
    assert not json_depth_exceeds(b'{"a": "[[[[[[[[[["}', 3)  # brackets inside strings
    assert not json_depth_exceeds(b'{"a": "\\"[[[[[["}', 3)


def test_client_reports_unreachable_service():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    c = PolicyClient(f"http://127.0.0.1:{port}", timeout=0.5)
    a, info = c.act(*_inputs())
    assert a is None and "error" in info
    with pytest.raises(ValueError):
        PolicyClient("ftp://127.0.0.1:1")


# -- limits ---------------------------------------------------------------------------------------

@pytest.fixture
def limited(policy):
    """Factory of servers with given limits, stopped at the end of the test."""
    servers = []

    def make(**limits):
        srv = PolicyServer(policy, port=0, **limits).start()
        servers.append(srv)
        return srv

    yield make
    for srv in servers:
        srv.stop()


def test_unknown_fields_are_refused_by_name(server, policy):
    o, g = _inputs()
    status, out = _request(server, "POST", "/act", {"observation": o.tolist(),
                                                    "desired_goal": g.tolist(), "id": 3,
                                                    "deterministic": True, "arm": 0})
    assert status == 400
    assert "unknown field(s) 'deterministic', 'arm'" in out["error"]
    status, out = _request(server, "POST", "/act", {"observation": o.tolist(),
                                                    "desired_goals": g.tolist()})
    assert status == 400
    assert "missing field(s) ['desired_goal']" in out["error"] and "'desired_goals'" in out["error"]
    status, out = _request(server, "POST", "/act", {"observation": o.tolist(),
                                                    "desired_goal": g.tolist(),
                                                    **{f"k{i}" * 30: 1 for i in range(8)}})
    assert status == 400 and "and 3 more" in out["error"] and len(out["error"]) < 600
    _assert_alive(server, policy)


@pytest.mark.parametrize("mb", [12, 50])
def test_oversized_body_sent_whole_gets_413(server, policy, mb):
    """A client that sends its whole body before reading (http.client) receives the 413: the
    server answers from the header, then drains the body instead of resetting the connection."""
    body = b"x" * (mb * 1024 * 1024)
    conn = http.client.HTTPConnection(*server.address, timeout=10)
    try:
        t0 = time.perf_counter()
        conn.request("POST", "/act", body=body, headers={"Content-Type": "application/json"})
        r = conn.getresponse()
        out = json.loads(r.read())
        ms = (time.perf_counter() - t0) * 1e3
    finally:
        conn.close()
    assert r.status == 413 and out["status"] == 413 and "exceeds the limit" in out["error"]
    assert r.getheader("Connection") == "close"
    print(f"\n[measured] {mb} MB body sent whole: 413 received {ms:.1f} ms after the request "
          f"started")
    _assert_alive(server, policy)


def test_drain_is_bounded_and_expect_100_is_refused_early(limited, policy):
    srv = limited(max_drain=256 * 1024)
    # a body far over the drain bound: the server closes after 256 KiB; the client's send fails
    # (or it reads the 413), and the service goes on
    with socket.create_connection(srv.address, timeout=10) as s:
        s.sendall(b"POST /act HTTP/1.1\r\nHost: x\r\nContent-Length: 100000000\r\n\r\n")
        t0, sent = time.perf_counter(), 0
        with pytest.raises(OSError):
            while sent < 100_000_000:
                sent += s.send(b"x" * 65536)
        assert sent < 20_000_000 and time.perf_counter() - t0 < 5.0
    # Expect: 100-continue with a body over the limit: the final 413 instead of 100 Continue
    with socket.create_connection(srv.address, timeout=10) as s:
        s.sendall(b"POST /act HTTP/1.1\r\nHost: x\r\nContent-Length: 10000000\r\n"
                  b"Expect: 100-continue\r\n\r\n")
        assert s.recv(65536).startswith(b"HTTP/1.1 413")
    # ... and 100 Continue for a body within it
    o, g = _inputs()
    body = json.dumps({"observation": o.tolist(), "desired_goal": g.tolist()}).encode()
    with socket.create_connection(srv.address, timeout=10) as s:
        s.sendall(b"POST /act HTTP/1.1\r\nHost: x\r\nContent-Length: %d\r\n"
                  b"Expect: 100-continue\r\n\r\n" % len(body))
        assert s.recv(65536).startswith(b"HTTP/1.1 100")
        s.sendall(body)
        assert s.recv(65536).startswith(b"HTTP/1.1 200")
    _assert_alive(srv, policy)


def _trickle(sock, data: bytes, period: float, result: dict, t0: float | None = None):
    """Sends ``data`` on ``sock`` one byte per ``period`` s until the server answers; records
    when (s from ``t0``, default the call: the request's first byte) and what."""
    sock.setblocking(False)
    t0 = time.perf_counter() if t0 is None else t0
    got, i = b"", 0
    while time.perf_counter() - t0 < 8.0:
        try:
            c = sock.recv(65536)
            if not c:
                break
            got += c
            result.setdefault("answered_s", time.perf_counter() - t0)
        except BlockingIOError:
            pass
        except OSError:
            break
        if "answered_s" not in result and i < len(data):
            try:
                sock.send(data[i:i + 1])
            except OSError:
                break
            i += 1
        time.sleep(period)
    result.update(answer=got, closed_s=time.perf_counter() - t0, bytes_sent=i)


def test_trickling_clients_are_cut_at_the_deadline(limited, policy):
    """One client trickles its request line and headers, one its body (a byte every 0.1 s): both
    get 408 when the 1 s deadline passes, and another client is served all the while."""
    srv = limited(request_timeout=1.0)
    o, g = _inputs()
    body = json.dumps({"observation": o.tolist(), "desired_goal": g.tolist()}).encode()
    head = b"POST /act HTTP/1.1\r\nHost: x\r\nContent-Length: %d\r\n\r\n" % len(body)
    socks = [socket.create_connection(srv.address, timeout=10) for _ in range(2)]
    results = [{}, {}]
    try:
        t_head = time.perf_counter()
        socks[1].sendall(head)  # headers at once, then the body byte by byte
        threads = [threading.Thread(target=_trickle, args=(socks[0], head + body, 0.1,
                                                           results[0])),
                   threading.Thread(target=_trickle, args=(socks[1], body, 0.1, results[1],
                                                           t_head))]
        for t in threads:
            t.start()
        client, served, t0 = PolicyClient(srv.url, timeout=5), 0, time.perf_counter()
        while any(t.is_alive() for t in threads) and time.perf_counter() - t0 < 10:
            a, info = client.act(o, g)
            assert a is not None, info
            served += 1
            time.sleep(0.005)
        for t in threads:
            t.join(timeout=10)
        client.close()
    finally:
        for sk in socks:
            sk.close()
    for name, r in zip(("headers", "body"), results, strict=True):
        assert r["answer"].startswith(b"HTTP/1.1 408"), (name, r)
        assert b"Connection: close" in r["answer"] and b'"status":408' in r["answer"]
        assert 0.9 <= r["answered_s"] <= 2.0, (name, r)
        assert r["closed_s"] < 4.0, (name, r)  # the server closed the connection too
    assert served >= 20 and srv.stats["timeouts"] == 2
    print(f"\n[measured] trickling clients (1 byte / 0.1 s) cut with 408 at "
          f"{results[0]['answered_s']:.2f} s (headers) and {results[1]['answered_s']:.2f} s "
          f"(body) of a 1 s deadline; {served} requests of another client served meanwhile")
    _assert_alive(srv, policy)


def test_idle_keepalive_connection_is_closed(limited, policy):
    srv = limited(idle_timeout=0.3, request_timeout=5.0)
    client = PolicyClient(srv.url, timeout=5)
    assert client.act(*_inputs())[0] is not None
    sock = client._sock
    t0 = time.perf_counter()
    sock.settimeout(5)
    assert sock.recv(100) == b""  # the server closed the idle connection
    assert 0.25 <= time.perf_counter() - t0 < 2.0
    a, info = client.act(*_inputs())  # sent again on a new connection: no missed deadline
    assert a is not None, info
    assert client._sock is not sock
    client.close()


def test_connection_cap(limited, policy):
    """With 2 connections open, a third gets 503 and is closed; once one of the two closes, a
    new connection is served."""
    srv = limited(max_connections=2)
    held = [PolicyClient(srv.url, timeout=5) for _ in range(2)]
    for c in held:
        assert c.act(*_inputs())[0] is not None  # admitted and kept open
    assert srv.stats["connections"] == 2
    o, g = _inputs()
    body = json.dumps({"observation": o.tolist(), "desired_goal": g.tolist()}).encode()
    t0 = time.perf_counter()
    ans = _raw(srv, b"POST /act HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                    b"Content-Length: %d\r\n\r\n%s" % (len(body), body))
    ms = (time.perf_counter() - t0) * 1e3
    assert ans.startswith(b"HTTP/1.1 503") and b"Connection: close" in ans
    assert b"Retry-After: 1" in ans and b"over capacity" in ans
    third = PolicyClient(srv.url, timeout=5)
    a, info = third.act(o, g)
    assert a is None and "HTTP 503" in info["error"]
    assert srv.stats["refused"] == 2
    held.pop().close()
    deadline = time.monotonic() + 5
    while srv.stats["connections"] >= 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    a, info = third.act(o, g)
    assert a is not None, info
    assert held[0].act(o, g)[0] is not None  # the connection still open was never disturbed
    print(f"\n[measured] connection cap 2: a third client's request answered 503 in {ms:.1f} ms")
    for c in (*held, third):
        c.close()


def test_limits_are_validated_and_configurable(policy, tmp_path, capsys):
    from daddpg_jax.cli import serve

    for bad in ({"max_connections": 0}, {"request_timeout": 0.0}, {"idle_timeout": float("inf")},
                {"max_body": 0}, {"max_drain": -1}):
        with pytest.raises(ValueError):
            ServiceLimits(**bad)
    srv = PolicyServer(policy, port=0, limits=ServiceLimits(request_timeout=0.5, max_connections=3))
    assert srv.limits.request_timeout == 0.5 and srv.httpd.limits.max_connections == 3
    srv.httpd.server_close()
    assert serve.main([str(tmp_path / "p.npz"), "--max-connections", "0"]) == 2
    assert "max_connections must be at least 1" in capsys.readouterr().err
    assert serve.main([str(tmp_path / "p.npz"), "--request-timeout", "-1"]) == 2
    assert "request_timeout" in capsys.readouterr().err


class _SlowGraphPolicy:
    """A policy whose compute is stopped at its cap (as ``OnnxPolicy.act`` raises it)."""

    def __init__(self, inner):
        self._inner = inner

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def act(self, o, g):
        from daddpg_jax.deploy.onnx_policy import ComputeTimeout

        raise ComputeTimeout("the ONNX graph ran past its compute cap of 0.5 s and was stopped")


def test_policy_stopped_at_its_compute_cap_gets_500(policy):
    """A policy call stopped at its compute-time cap (ComputeTimeout, a RuntimeError: not an
    OSError that would drop the connection unanswered) is answered 500 with the reason and
    ``Connection: close``, no action; the service keeps serving; ~0.1 s."""
    with PolicyServer(_SlowGraphPolicy(policy), port=0) as srv:
        o, g = _inputs(3)
        body = json.dumps({"observation": o.tolist(), "desired_goal": g.tolist()}).encode()
        ans = _raw(srv, b"POST /act HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                        b"Content-Length: %d\r\n\r\n" % len(body) + body)
        assert ans.startswith(b"HTTP/1.1 500 ") and b"Connection: close" in ans, ans[:300]
        assert b"compute cap" in ans and b"no action is sent" in ans and b'"action"' not in ans
        status, out = _request(srv, "GET", "/health")
        assert status == 200 and out["errors"] == 1
