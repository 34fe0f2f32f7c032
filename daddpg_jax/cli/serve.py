"""Serve an exported policy over HTTP + JSON (the decision service the robot queries).

Examples (daddpg-serve = python experiments/serve.py)
  daddpg-serve policy.npz                       # http://127.0.0.1:8000
  daddpg-serve policy.npz --port 8100 --verbose

Endpoints: POST /act {"observation": [[25],[25]], "desired_goal": [[3],[3]]} -> {"action": [8],
"per_arm": [[4],[4]], "latency_ms"}; GET /health; GET /info. Loopback by default: binding
another address exposes an unauthenticated service that moves a robot (docs/DEPLOYMENT.md).
No JAX is imported.
"""

from __future__ import annotations

import argparse
import sys


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="serve.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policy", help="exported .npz (daddpg-export)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default loopback)")
    p.add_argument("--port", type=int, default=8000, help="port (default 8000; 0 = any free)")
    p.add_argument("--max-body", type=int, default=64 * 1024, help="largest request body, bytes")
    p.add_argument("--verbose", action="store_true", help="log every request to stderr")
    args = p.parse_args(argv)

    from daddpg_jax.deploy import NumpyPolicy, PolicyFormatError
    from daddpg_jax.deploy.server import PolicyServer

    try:
        policy = NumpyPolicy.load(args.policy)
    except (FileNotFoundError, PolicyFormatError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    try:
        server = PolicyServer(policy, host=args.host, port=args.port, max_body=args.max_body,
                              verbose=args.verbose)
    except OSError as e:
        print(f"error: cannot bind {args.host}:{args.port}: {e}", file=sys.stderr)
        return 2
    print(f"serving {policy.task}/{policy.algo} policy on {server.url} "
          f"(POST /act, GET /health, GET /info); Ctrl-C stops", flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.httpd.server_close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
