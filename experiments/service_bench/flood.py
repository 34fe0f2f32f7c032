"""The flood benchmark of the policy service behind
``experiments/service_bench/bench_flood.py`` (which holds its flags): a robot probe polling
POST /act once per control period, alone and while flooder connections (their own process)
send the largest malformed bodies the service reads. Loopback only, bounded in time and connections.
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import threading
import time

import numpy as np

from daddpg_jax.deploy.client import PolicyClient
from daddpg_jax.deploy.robot import Pacer

MAX_SECONDS = 120.0
MAX_FLOODERS = 64
FLOOD_SCRIPT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "bench_flood.py")
"""the script the flooders' process runs (with --flood-only URL)"""
BODY_KINDS = ("nesting", "numbers", "strings")


def malformed_body(size: int, kind: str) -> bytes:
    """``size`` bytes of malformed JSON that the service must read and scan whole: deep
    nesting, a long list of numbers left open, or escaped brackets inside an open string."""
    if kind == "nesting":
        return b"[" * size
    if kind == "numbers":
        return (b"[" + b"1," * size)[:size]
    return (b'["' + b"\\[" * size)[:size]


def _flood_worker(host, port, body: bytes, stop, counts, i):
    head = (b"POST /act HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            b"Content-Length: %d\r\n\r\n" % len(body))
    req = head + body
    while not stop.is_set():
        try:
            with socket.create_connection((host, port), timeout=5) as s:
                while not stop.is_set():
                    s.sendall(req)
                    got = b""
                    while b"\r\n\r\n" not in got:
                        c = s.recv(65536)
                        if not c:
                            raise ConnectionError
                        got += c
                    head_end = got.index(b"\r\n\r\n") + 4
                    n = int(re.search(rb"Content-Length: (\d+)", got).group(1))
                    while len(got) < head_end + n:
                        got += s.recv(65536)
                    counts[i] += 1
                    if b"Connection: close" in got[:head_end]:
                        break
        except (OSError, AttributeError, ValueError):
            time.sleep(0.01)


def flood(host: str, port: int, n: int, body: bytes, seconds: float) -> int:
    """``n`` connections sending ``body`` over keep-alive for ``seconds``; the answers read."""
    stop, counts = threading.Event(), [0] * n
    threads = [threading.Thread(target=_flood_worker, args=(host, port, body, stop, counts, i),
                                daemon=True) for i in range(n)]
    for t in threads:
        t.start()
    time.sleep(seconds)
    stop.set()
    for t in threads:
        t.join(timeout=5)
    return sum(counts)


def _start_flooders(url: str, n: int, kind: str, size: int, seconds: float):
    """The flooders in their own process (``--flood-only``): they must not share the probe's
    interpreter lock."""
    return subprocess.Popen([sys.executable, FLOOD_SCRIPT, "--flood-only",
                             url, "--flooders", str(n), "--kind", kind, "--max-body", str(size),
                             "--seconds", str(seconds)], stdout=subprocess.PIPE, text=True)


def probe(url: str, seconds: float, period: float = 0.04, deadline: float = 0.04,
          obs_size: int = 25) -> dict:
    """Polls POST /act once per ``period`` for ``seconds`` with a ``deadline`` per request."""
    c = PolicyClient(url, timeout=deadline)
    o, g = np.zeros((2, obs_size)), np.full((2, 3), 0.3)
    pacer, rtts, missed = Pacer(period), [], 0
    t_end = time.perf_counter() + seconds
    while time.perf_counter() < t_end:
        pacer.wait()
        t0 = time.perf_counter()
        a, info = c.act(o, g)
        rtt = time.perf_counter() - t0
        rtts.append(rtt * 1e3)
        if a is None or rtt > deadline:
            missed += 1
    c.close()
    r = np.asarray(rtts)
    return dict(requests=len(rtts), missed=missed, rtt_ms_p50=round(float(np.median(r)), 2),
                rtt_ms_p99=round(float(np.percentile(r, 99)), 2),
                rtt_ms_max=round(float(r.max()), 2), overruns=pacer.overruns)


def start_service(policy: str, max_body: int):
    proc = subprocess.Popen([sys.executable, "-m", "daddpg_jax.cli.serve", policy, "--port", "0",
                             "--max-body", str(max_body)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, JAX_PLATFORMS="cpu"))
    line = proc.stdout.readline()
    m = re.search(r" on (http://\S+) \(", line)
    if not m:
        proc.kill()
        raise RuntimeError(f"the service did not start: {proc.stderr.read().strip()}")
    return proc, m.group(1)


def run_phases(policy: str, flooders: int, kind: str, max_body: int, seconds: float) -> dict:
    """Serves `policy` (its own process), probes it alone, then while `flooders` connections
    send malformed bodies; the result. RuntimeError when the service does not start."""
    proc, url = start_service(policy, max_body)
    flood_proc = None
    try:
        alone = probe(url, seconds)
        flood_proc = _start_flooders(url, flooders, kind, max_body, seconds + 1.0)
        time.sleep(0.5)  # the flood under way
        flooded = probe(url, seconds)
        out_text, _ = flood_proc.communicate(timeout=seconds + 30)
        refused = int(out_text.strip() or 0)
    finally:
        for pr in (flood_proc, proc):
            if pr is not None and pr.poll() is None:
                pr.terminate()
                pr.wait(timeout=10)
    return dict(machine=f"{os.cpu_count()}-core CPU", flooders=flooders, kind=kind,
                body_bytes=max_body, seconds=seconds, deadline_ms=40.0,
                period_ms=40.0, alone=alone, flooded=flooded,
                malformed_bodies_refused=refused,
                malformed_per_s=round(refused / (seconds + 1.0), 1))
