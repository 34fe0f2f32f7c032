"""Deadlines hold end to end: one monotonic deadline per request covers connect, send, headers
and body, with a cap on the answer's size. Against a test service that trickles, stalls, floods
and lies, the paced control loop holds both arms within the period: the p99 of the control
periods stays within the deadline plus 10 ms. An honest service gives a normal paced run.

In-process (a raw-socket service in a thread, the NumPy simulator, the checked-in export
tests/data/legacy_reach/policy.npz; no JAX): ~1 s per service behaviour, ~10 s the module."""

from __future__ import annotations

import json
import os
import socket
import threading
import time
import tracemalloc

import numpy as np
import pytest

from daddpg_jax.deploy import NumpyPolicy, robot
from daddpg_jax.deploy.client import PolicyClient
from daddpg_jax.deploy.limits import RobotLimits
from daddpg_jax.deploy.safety import SafetyFilter
from daddpg_jax.deploy.server import PolicyServer
from mjx_envs.numpy_env import NumpyDualArmEnv

pytestmark = pytest.mark.usefixtures("arm_recorder")  # every command checked

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GOOD = os.path.join(ROOT, "tests", "data", "legacy_reach", "policy.npz")
PERIOD, DEADLINE = 0.04, 0.03
STEPS = 25


class BadService:
    """Answers each request in one of these ways (loopback, a thread per connection):

    trickle: a valid answer, its headers one byte per 20 ms; stall: reads the request, never
    answers; flood: a 400 MB answer streamed as fast as the socket takes it; chunks: an endless
    chunked body; lie_length: Content-Length 1000 with a 200-byte body, then silence; nan: a
    200 with NaN actions; strings: actions as strings; huge: 1e300 actions (inf in float32);
    slow_accept: never accepts (connect succeeds into the backlog)."""

    def __init__(self, mode: str):
        self.mode, self.sent, self.stop = mode, 0, threading.Event()
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}"
        if mode != "slow_accept":
            threading.Thread(target=self._accept, daemon=True).start()

    def close(self):
        self.stop.set()
        self.sock.close()

    def _accept(self):
        while not self.stop.is_set():
            try:
                c, _ = self.sock.accept()
            except OSError:
                return
            threading.Thread(target=self._serve, args=(c,), daemon=True).start()

    @staticmethod
    def _read_request(c) -> dict | None:
        buf = b""
        while b"\r\n\r\n" not in buf:
            d = c.recv(65536)
            if not d:
                return None
            buf += d
        head, _, body = buf.partition(b"\r\n\r\n")
        n = [int(h.split(b":")[1]) for h in head.split(b"\r\n")
             if h.lower().startswith(b"content-length")]
        while n and len(body) < n[0]:
            body += c.recv(65536)
        return json.loads(body) if body else {}

    def _answer(self, req, action) -> bytes:
        body = json.dumps({"action": action, "id": req.get("id")}).encode()
        if self.mode == "nan":
            body = body.replace(b"0.1", b"NaN")
        return b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: %d\r\n\r\n" \
            % len(body) + body

    def _serve(self, c):
        c.settimeout(10)
        try:
            while not self.stop.is_set():
                req = self._read_request(c)
                if req is None:
                    return
                m = self.mode
                if m == "trickle":
                    for b in self._answer(req, [0.1] * 8):
                        c.sendall(bytes([b]))
                        time.sleep(0.02)
                elif m == "stall":
                    self.stop.wait(10)
                elif m in ("flood", "chunks"):
                    head = (b"HTTP/1.1 200 OK\r\nContent-Length: 400000000\r\n\r\n" if m == "flood"
                            else b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\n")
                    c.sendall(head)
                    chunk = b"0" * 65536 if m == "flood" else b"10000\r\n" + b"0" * 65536 + b"\r\n"
                    while not self.stop.is_set():
                        self.sent += c.send(chunk)
                elif m == "lie_length":
                    body = json.dumps({"action": [0.1] * 8, "id": req.get("id")}).encode()
                    c.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: 1000\r\n\r\n" + body)
                    self.stop.wait(10)
                elif m == "nan":
                    c.sendall(self._answer(req, [0.1] * 8))
                elif m == "strings":
                    c.sendall(self._answer(req, ["1"] * 8))
                elif m == "huge":
                    c.sendall(self._answer(req, [1e300] * 8))
        except OSError:
            pass
        finally:
            c.close()


@pytest.fixture(scope="module")
def policy():
    return NumpyPolicy.load(GOOD)


class _NoAnswer:
    def act(self, o, g):
        return None, {"error": "warm-up"}


@pytest.fixture(scope="module")
def env(policy):
    """The simulator, with one unpaced episode run first (first calls pay one-time costs that
    are not the loop's)."""
    e = NumpyDualArmEnv(policy.env, task="reach")
    e.episode_length = STEPS
    limits = RobotLimits.load(os.path.join(ROOT, "daddpg_jax", "deploy", "limits", "sim.toml"))
    robot.run_episode(e, _NoAnswer(), SafetyFilter(limits.safety_limits()),
                      goal=np.zeros((2, 3)), log={}, max_observation_age=1.0)
    return e


def _paced_episode(env, url):
    limits = RobotLimits.load(os.path.join(ROOT, "daddpg_jax", "deploy", "limits", "sim.toml"))
    limits = limits.tightened(deadline=DEADLINE)
    safety = SafetyFilter(limits.safety_limits())
    client = PolicyClient(url, timeout=DEADLINE)
    pacer = robot.Pacer(PERIOD)
    home = env.reset(goal=np.zeros((2, 3))).achieved_goal
    log: dict = {}
    try:
        out = robot.run_episode(env, client, safety, goal=np.zeros((2, 3)), pacer=pacer,
                                max_observation_age=limits.max_observation_age, log=log)
    finally:
        client.close()
    return out, log, home, pacer


MODES = ["trickle", "stall", "flood", "chunks", "lie_length", "nan", "strings", "huge",
         "slow_accept"]


STEP_MS: dict[str, list[float]] = {}  # mode -> the step times of its episode, ms


@pytest.mark.parametrize("mode", MODES)
def test_bad_service_holds_both_arms_within_the_period(env, mode):
    """A service that trickled its headers one byte per 20 ms stalled one 40 ms period for
    25 s before; now the periods of the paced loop end within the deadline + 10 ms (90% of
    them here, 99% over all behaviours in the next test; a loaded machine may delay one), and
    both arms hold (every period is a stop, the targets never move)."""
    bad = BadService(mode)
    try:
        out, log, home, pacer = _paced_episode(env, bad.url)
    finally:
        bad.close()
    assert out["stops"] == STEPS, (mode, out["errors"])
    targets = np.array([s["target"] for s in log["steps"]])
    np.testing.assert_allclose(targets, np.broadcast_to(targets[0], targets.shape))
    assert all(s["stopped"] for s in log["steps"])
    step_ms = np.array([s["step_ms"] for s in log["steps"]])
    STEP_MS[mode] = step_ms.tolist()
    assert np.percentile(step_ms, 90) <= (DEADLINE + 0.010) * 1e3, (mode, step_ms)
    # never the 25 s of before; as the docstring says, a loaded 2-core machine may delay one
    # period (a 0.42 s scheduling gap was seen once in CI, with the other test worker busy)
    assert np.sum(step_ms >= 100.0) <= 1 and step_ms.max() < 1000.0, (mode, step_ms)
    print(f"\n[measured] {mode}: step p50 {np.median(step_ms):.1f} ms, max "
          f"{step_ms.max():.1f} ms (deadline {DEADLINE * 1e3:g} ms, period "
          f"{PERIOD * 1e3:g} ms); {pacer.overruns} overruns")


def test_p99_of_the_periods_over_all_bad_services():
    """The p99 of the step times over every behaviour above (9 x 25 periods) stays within the
    deadline + 10 ms; runs after them (skipped when run alone)."""
    if set(STEP_MS) != set(MODES):
        pytest.skip("needs every case of test_bad_service_holds_both_arms_within_the_period")
    pooled = np.concatenate([STEP_MS[m] for m in MODES])
    p99 = float(np.percentile(pooled, 99))
    print(f"\n[measured] all bad services: {pooled.size} periods, step p99 {p99:.1f} ms, max "
          f"{pooled.max():.1f} ms (deadline {DEADLINE * 1e3:g} ms)")
    assert p99 <= (DEADLINE + 0.010) * 1e3, p99


def test_flood_is_read_only_up_to_the_answer_cap():
    """A 400 MB answer was read whole (885 MB RSS); now at most ``max_answer`` bytes."""
    bad = BadService("flood")
    try:
        c = PolicyClient(bad.url, timeout=2.0, max_answer=64 * 1024)
        tracemalloc.start()
        t0 = time.perf_counter()
        a, info = c.act(np.zeros((2, 25)), np.zeros((2, 3)))
        took = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        c.close()
    finally:
        bad.close()
    assert a is None and "larger than 65536 bytes" in info["error"]
    assert took < 0.5 and peak < 2_000_000, (took, peak)


def test_honest_service_gives_a_normal_paced_run(env, policy):
    """Positive control: the same paced loop against the real service: no missed deadline
    (at most one on a loaded machine), periods of 40 ms."""
    with PolicyServer(policy, port=0) as srv:
        out, log, _, pacer = _paced_episode(env, srv.url)
    assert out["stops"] <= 1, out["errors"]
    t = np.array([s["t"] for s in log["steps"]])
    periods = np.diff(t)
    assert np.median(periods) == pytest.approx(PERIOD, abs=0.002)
    assert out["step_ms_p99"] <= (DEADLINE + 0.010) * 1e3
    assert all(s["server_ms"] is not None for s in log["steps"] if not s["stopped"])
