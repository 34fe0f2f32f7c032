"""Latency and throughput of the policy service on loopback, behind
``experiments/service_bench/bench_server.py`` (which holds its flags): client
threads, one HTTP/1.1 connection each, sending POST /act back to back.
"""

from __future__ import annotations

import re
import subprocess
import sys
import threading
import time
from urllib.parse import urlsplit

import numpy as np

from daddpg_jax.deploy.server import PolicyClient
from daddpg_jax.running.host import host_info

LOOPBACK = ("127.0.0.1", "localhost", "::1")


def bench(url: str, requests: int, clients: int, warmup: int, obs_size: int, seed: int = 0) -> dict:
    per = [requests // clients + (1 if i < requests % clients else 0) for i in range(clients)]
    rtts: list[list[float]] = [[] for _ in range(clients)]
    server_ms: list[list[float]] = [[] for _ in range(clients)]
    errors = [0] * clients
    barrier = threading.Barrier(clients + 1)

    def worker(i):
        rng = np.random.default_rng(seed + i)
        c = PolicyClient(url, timeout=10.0)
        obs = rng.normal(0, 0.2, (64, 2, obs_size)).astype(np.float32)
        goal = rng.uniform(0.0, 0.5, (64, 2, 3)).astype(np.float32)
        for k in range(warmup):
            c.act(obs[k % 64], goal[k % 64])
        barrier.wait()
        for k in range(per[i]):
            t0 = time.perf_counter()
            a, info = c.act(obs[k % 64], goal[k % 64])
            elapsed_s = time.perf_counter() - t0
            if a is None:
                errors[i] += 1
                continue
            rtts[i].append(elapsed_s * 1e3)
            server_ms[i].append(info.get("server_ms") or 0.0)
        c.close()

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(clients)]
    for t in threads:
        t.start()
    barrier.wait()
    t0 = time.perf_counter()
    for t in threads:
        t.join()
    wall = time.perf_counter() - t0
    all_rtt = np.concatenate([np.asarray(r) for r in rtts]) if requests else np.zeros(0)
    all_srv = np.concatenate([np.asarray(r) for r in server_ms]) if requests else np.zeros(0)

    def pct(q):
        return round(float(np.percentile(all_rtt, q)), 3) if all_rtt.size else None

    return dict(requests=int(requests), clients=int(clients), errors=int(sum(errors)),
                wall_s=round(wall, 3), requests_per_s=round(all_rtt.size / wall, 1),
                rtt_ms_p50=pct(50), rtt_ms_p90=pct(90), rtt_ms_p99=pct(99),
                rtt_ms_max=round(float(all_rtt.max()), 3) if all_rtt.size else None,
                server_compute_ms_p50=round(float(np.median(all_srv)), 4) if all_srv.size else None)


def start_service(policy_path: str, timeout_s: float = 60.0):
    """Starts the policy service (daddpg_jax.cli.serve) on a free loopback port; returns
    (process, url)."""
    proc = subprocess.Popen([sys.executable, "-m", "daddpg_jax.cli.serve", policy_path,
                             "--host", "127.0.0.1", "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    t_end = time.monotonic() + timeout_s
    line = ""
    while time.monotonic() < t_end:
        line = proc.stdout.readline()
        m = re.search(r"(http://127\.0\.0\.1:\d+)", line)
        if m:
            return proc, m.group(1)
        if not line and proc.poll() is not None:
            break
    proc.kill()
    raise RuntimeError(f"serve.py did not start: {line.strip()!r}")


def not_loopback(url: str) -> str | None:
    """The error text for a --url that is not a loopback address, else None."""
    host = urlsplit(url if "://" in url else f"http://{url}").hostname
    if host not in LOOPBACK:
        return f"--url must be a loopback address ({', '.join(LOOPBACK)}), got {host!r}"
    return None


def served_policy(url: str):
    """(obs_size, task, algo, layer_sizes) of the policy a running service at `url` serves."""
    info = PolicyClient(url).info()
    return info["obs_size"], info["task"], info["algo"], info["layer_sizes"]


def machine() -> dict:
    """The host's description (running.host.host_info) with the numpy version."""
    return dict(host_info(), numpy=np.__version__)
