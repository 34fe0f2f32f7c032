"""The service benchmarks (experiments/service_bench): their own code in this process against
a service in this process (< 1 s), and the flood benchmark's bounded run (e2e, ~5 s)."""

import json
import os

import pytest

from daddpg_jax.deploy import NumpyPolicy
from daddpg_jax.deploy.server import PolicyServer
from experiments.service_bench import bench_flood, bench_server

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GOOD = os.path.join(ROOT, "tests", "data", "legacy_reach", "policy.npz")


@pytest.fixture(scope="module")
def policy():
    return NumpyPolicy.load(GOOD)


@pytest.fixture(scope="module")
def server(policy):
    with PolicyServer(policy, port=0) as srv:
        yield srv


@pytest.mark.e2e
def test_flood_benchmark_runs_bounded(tmp_path):
    """The flood benchmark (service and flooders in their own processes), shortened: 2
    flooders, two phases of 1 s; ~5 s. The figures in docs/RELIABILITY.md come from its full
    run."""
    out_json = tmp_path / "flood.json"
    assert bench_flood.main([GOOD, "--flooders", "2", "--seconds", "1", "--json",
                             str(out_json)]) == 0
    out = json.loads(out_json.read_text())
    assert out["malformed_bodies_refused"] > 10
    for phase in ("alone", "flooded"):
        assert 20 <= out[phase]["requests"] <= 30 and out[phase]["rtt_ms_p50"] < 40
    assert bench_flood.malformed_body(100, "numbers")[:3] == b"[1,"
    with pytest.raises(SystemExit):
        bench_flood.main([GOOD, "--flooders", "1000"])


def test_benchmark_tools_in_process(server, policy, capsys):
    """The two service benchmarks' own code in this process (< 1 s): bench_server's timed
    clients against the module's service, and bench_flood's malformed bodies and argument
    checks. Their full runs (own processes) are in the e2e tier and docs/RELIABILITY.md."""
    r = bench_server.bench(server.url, requests=30, clients=3, warmup=2, obs_size=policy.obs_size)
    assert r["requests"] == 30 and r["clients"] == 3 and r["errors"] == 0
    assert 0 < r["rtt_ms_p50"] <= r["rtt_ms_p99"] <= r["rtt_ms_max"]
    assert r["requests_per_s"] > 0 and r["server_compute_ms_p50"] >= 0
    for argv in (["--requests", "0", GOOD], ["--clients", "33", GOOD], []):
        with pytest.raises(SystemExit) as e:
            bench_server.main(argv)
        assert e.value.code == 2
    assert bench_flood.malformed_body(5, "nesting") == b"[[[[["
    assert bench_flood.malformed_body(6, "numbers") == b"[1,1,1"
    assert bench_flood.malformed_body(7, "strings") == b'["\\[\\[\\'
    for kind in bench_flood.BODY_KINDS:
        body = bench_flood.malformed_body(1000, kind)
        assert len(body) == 1000
        with pytest.raises((ValueError, RecursionError)):   # deep nesting: RecursionError
            json.loads(body)
    with pytest.raises(SystemExit):
        bench_flood.main([GOOD, "--flooders", "1000"])
    capsys.readouterr()
