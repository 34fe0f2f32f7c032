"""Flood benchmark of the policy service (loopback only, bounded in time and connections).

Starts daddpg-serve on a policy file (its own process), then runs a robot probe that polls
POST /act once per control period (25 Hz) with a 40 ms deadline, first alone, then while
--flooders connections (in a second process) send the largest malformed bodies the service
reads (a well-framed body of max_body bytes that is not valid JSON, over keep-alive, as fast as
the service answers). Reports the probe's round-trip times (p50, p99, max) and missed deadlines
in both phases, and how many malformed bodies the service refused meanwhile.

Examples
  python experiments/bench_flood.py tests/data/legacy_reach/policy.npz
  python experiments/bench_flood.py policy.npz --flooders 16 --seconds 10 --json flood.json
"""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
import subprocess
import sys
import threading
import time

MAX_SECONDS = 120.0
MAX_FLOODERS = 64
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
    return subprocess.Popen([sys.executable, "-m", "daddpg_jax.cli.bench_flood", "--flood-only",
                             url, "--flooders", str(n), "--kind", kind, "--max-body", str(size),
                             "--seconds", str(seconds)], stdout=subprocess.PIPE, text=True)


def probe(url: str, seconds: float, period: float = 0.04, deadline: float = 0.04,
          obs_size: int = 25) -> dict:
    """Polls POST /act once per ``period`` for ``seconds`` with a ``deadline`` per request."""
    import numpy as np

    from daddpg_jax.deploy.client import PolicyClient
    from daddpg_jax.deploy.robot import Pacer

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


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench_flood.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policy", nargs="?", help="exported .npz to serve")
    p.add_argument("--flood-only", default=None, metavar="URL", help=argparse.SUPPRESS)
    p.add_argument("--flooders", type=int, default=16, help="flooding connections (default 16)")
    p.add_argument("--seconds", type=float, default=10.0, help="length of each phase, s")
    p.add_argument("--kind", choices=BODY_KINDS, default="nesting",
                   help="malformed body (default nesting: '[' * max_body)")
    p.add_argument("--max-body", type=int, default=64 * 1024,
                   help="the service's body limit; each flood body is this large")
    p.add_argument("--json", default=None, help="also write the result to this JSON file")
    args = p.parse_args(argv)
    if not 1 <= args.flooders <= MAX_FLOODERS:
        p.error(f"--flooders must be in 1..{MAX_FLOODERS}")
    if not 0.5 <= args.seconds <= MAX_SECONDS:
        p.error(f"--seconds must be in 0.5..{MAX_SECONDS:g}")
    if args.flood_only:  # the flooders' process: print how many bodies were answered
        host, port = args.flood_only.rsplit("//", 1)[1].rsplit(":", 1)
        print(flood(host, int(port), args.flooders, malformed_body(args.max_body, args.kind),
                    args.seconds), flush=True)
        return 0
    if args.policy is None:
        p.error("give a policy file")
    if not os.path.exists(args.policy):
        print(f"error: policy file {args.policy!r} not found", file=sys.stderr)
        return 2
    try:
        proc, url = start_service(args.policy, args.max_body)
    except RuntimeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    flooders = None
    try:
        alone = probe(url, args.seconds)
        flooders = _start_flooders(url, args.flooders, args.kind, args.max_body,
                                   args.seconds + 1.0)
        time.sleep(0.5)  # the flood under way
        flooded = probe(url, args.seconds)
        out_text, _ = flooders.communicate(timeout=args.seconds + 30)
        refused = int(out_text.strip() or 0)
    finally:
        for pr in (flooders, proc):
            if pr is not None and pr.poll() is None:
                pr.terminate()
                pr.wait(timeout=10)
    out = dict(machine=f"{os.cpu_count()}-core CPU", flooders=args.flooders, kind=args.kind,
               body_bytes=args.max_body, seconds=args.seconds, deadline_ms=40.0,
               period_ms=40.0, alone=alone, flooded=flooded,
               malformed_bodies_refused=refused,
               malformed_per_s=round(refused / (args.seconds + 1.0), 1))
    print(json.dumps(out, indent=2))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
