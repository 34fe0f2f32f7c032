"""Latency and throughput of the policy service on loopback (bounded, loopback only).

Examples
  python experiments/bench_server.py policy.npz                        # starts serve.py itself
  python experiments/bench_server.py policy.npz --requests 2000 --clients 4 --json bench.json
  python experiments/bench_server.py --url http://127.0.0.1:8000 --requests 1000

With a policy file the service runs in its own process (experiments/serve.py on a free loopback
port), as in deployment, so client and server do not share an interpreter lock. Each client
thread keeps one HTTP/1.1 connection and sends its share of POST /act requests with random
observations, one at a time (as a robot does once per control period, but back to back).
Reported: client round-trip p50/p90/p99/max (ms), the server's own compute time p50, and
requests/s over the whole run. Only loopback addresses are accepted.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time

LOOPBACK = ("127.0.0.1", "localhost", "::1")


def bench(url: str, requests: int, clients: int, warmup: int, obs_size: int, seed: int = 0) -> dict:
    import numpy as np

    from daddpg_jax.deploy.server import PolicyClient

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
            dt = time.perf_counter() - t0
            if a is None:
                errors[i] += 1
                continue
            rtts[i].append(dt * 1e3)
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
    import re
    import subprocess

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


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench_server.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policy", nargs="?", help="exported .npz to serve in-process (or use --url)")
    p.add_argument("--url", default=None, help="benchmark an already running loopback service")
    p.add_argument("--requests", type=int, default=2000, help="timed requests in all (max 100000)")
    p.add_argument("--clients", type=int, default=1, help="concurrent client threads (max 32)")
    p.add_argument("--warmup", type=int, default=50, help="untimed requests per client first")
    p.add_argument("--json", default=None, help="also write the result to this JSON file")
    args = p.parse_args(argv)
    if not 1 <= args.requests <= 100_000:
        p.error("--requests must be in 1..100000")
    if not 1 <= args.clients <= 32:
        p.error("--clients must be in 1..32")
    if (args.policy is None) == (args.url is None):
        p.error("give either a policy file or --url")

    from daddpg_jax.deploy import NumpyPolicy, PolicyFormatError
    from daddpg_jax.deploy.server import PolicyClient

    proc = None
    if args.url is not None:
        from urllib.parse import urlsplit

        host = urlsplit(args.url if "://" in args.url else f"http://{args.url}").hostname
        if host not in LOOPBACK:
            p.error(f"--url must be a loopback address ({', '.join(LOOPBACK)}), got {host!r}")
        url = args.url
        info = PolicyClient(url).info()
        obs_size, task, algo = info["obs_size"], info["task"], info["algo"]
        layers = info["layer_sizes"]
    else:
        try:
            policy = NumpyPolicy.load(args.policy)
        except (FileNotFoundError, PolicyFormatError) as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        proc, url = start_service(args.policy)
        obs_size, task, algo = policy.obs_size, policy.task, policy.algo
        layers = policy.meta["layer_sizes"]
    try:
        res = bench(url, args.requests, args.clients, args.warmup, obs_size)
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(timeout=10)
    import numpy

    from daddpg_jax.running.host import host_info

    args_text = " ".join(argv if argv is not None else sys.argv[1:])
    res.update(task=task, algo=algo, layer_sizes=layers, server="subprocess" if proc else url,
               machine=dict(host_info(), numpy=numpy.__version__),
               command="python experiments/bench_server.py " + args_text)
    print(json.dumps(res, indent=2))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
