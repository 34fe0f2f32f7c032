"""Serve an exported policy over HTTP + JSON (the decision service the robot queries).

Examples (daddpg-serve = python experiments/serve.py)
  daddpg-serve policy.npz                       # http://127.0.0.1:8000
  daddpg-serve policy.npz --port 8100 --verbose
  daddpg-serve policy.npz --request-timeout 2 --max-connections 8

Endpoints: POST /act {"observation": [[25],[25]], "desired_goal": [[3],[3]]} -> {"action": [8],
"per_arm": [[4],[4]], "latency_ms"}; GET /health; GET /info (with the policy file's SHA-256).
Loopback by default: binding another address exposes a service that moves a robot; a shared
token (--token-file) keeps out clients without it, but nothing is encrypted (no TLS): use a
private link (docs/DEPLOYMENT.md). A malformed, truncated or oversized policy file: one line,
exit 2.
Limits: body size (413), a deadline for each request's headers and body (408), keep-alive idle
time, open connections (503); see docs/RELIABILITY.md. No JAX is imported.
"""

from __future__ import annotations

import argparse
import sys

from daddpg_jax.deploy import PolicyFormatError
from daddpg_jax.deploy.client import read_token
from daddpg_jax.deploy.onnx_policy import load_policy  # .npz or .onnx, by extension
from daddpg_jax.deploy.server import (
    IDLE_TIMEOUT_S,
    MAX_BODY,
    MAX_CONNECTIONS,
    REQUEST_TIMEOUT_S,
    PolicyServer,
    ServiceLimits,
)

SWITCH_INTERVAL_S = 0.0005


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="daddpg-serve", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policy", help="exported policy, .npz or .onnx (daddpg-export; .onnx runs in "
                                  "onnxruntime: pip install 'daddpg-jax[onnx]')")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default loopback)")
    p.add_argument("--port", type=int, default=8000, help="port (default 8000; 0 = any free)")
    p.add_argument("--max-body", type=int, default=MAX_BODY,
                   help=f"largest request body, bytes (default {MAX_BODY}; larger: 413)")
    p.add_argument("--request-timeout", type=float, default=REQUEST_TIMEOUT_S,
                   help="seconds from a request's first byte to the end of its body (default "
                        f"{REQUEST_TIMEOUT_S:g}; later: 408 and the connection closed)")
    p.add_argument("--idle-timeout", type=float, default=IDLE_TIMEOUT_S,
                   help="seconds a keep-alive connection may wait between requests (default "
                        f"{IDLE_TIMEOUT_S:g})")
    p.add_argument("--max-connections", type=int, default=MAX_CONNECTIONS,
                   help=f"connections served at once (default {MAX_CONNECTIONS}; more: 503)")
    p.add_argument("--token-file", default=None, metavar="FILE",
                   help="require the shared token in this file (first line, 16-4096 visible "
                        "ASCII characters) in each request's X-Policy-Token header; without it: "
                        "401. Not encryption: see docs/DEPLOYMENT.md")
    p.add_argument("--verbose", action="store_true", help="log every request to stderr")
    args = p.parse_args(argv)
    try:
        limits = ServiceLimits(max_body=args.max_body, request_timeout=args.request_timeout,
                               idle_timeout=args.idle_timeout,
                               max_connections=args.max_connections)
        token = read_token(args.token_file) if args.token_file else None
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    try:
        policy = load_policy(args.policy)
    except (FileNotFoundError, PolicyFormatError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    try:
        server = PolicyServer(policy, host=args.host, port=args.port, limits=limits,
                              verbose=args.verbose, token=token)
    except OSError as e:
        print(f"error: cannot bind {args.host}:{args.port}: {e}", file=sys.stderr)
        return 2
    print(f"serving {policy.task}/{policy.algo} policy on {server.url} "
          f"(POST /act, GET /health, GET /info; request timeout {limits.request_timeout:g} s, "
          f"at most {limits.max_connections} connections{'; token required' if token else ''}"
          f"); policy sha256 {getattr(policy, 'sha256', None)}; Ctrl-C stops", flush=True)
    # this process only serves: switch threads every 0.5 ms instead of Python's 5 ms, so that
    # the thread of a robot's request gets the interpreter soon while others parse a flood
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.httpd.server_close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
