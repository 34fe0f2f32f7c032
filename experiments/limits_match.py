"""Does the trainer's success under a limits file match the robot client's? (docs/DEPLOYMENT.md,
"Training under the robot's limits")

For each run directory and each limits file: the run's best test success in training, its best
checkpoint evaluated by ``daddpg-evaluate --limits FILE --save-starts`` (seed 5: not the
episodes that chose the checkpoint), and the same checkpoint exported, served and run through
``daddpg-robot-client --arms sim --fast --limits FILE --starts`` over the same episodes (their
goals and initial states), so the two success rates are paired episode by episode: the row
holds their difference with its paired 95 % interval (Newcombe) and the episodes each side
alone solved. ``--unpaired`` draws the robot client's episodes from its own --seed instead (the
rows of earlier revisions). One JSON per run and file under --out::

    python experiments/limits_match.py runs/reach_plain runs/reach_sim \\
        --limits daddpg_jax/deploy/limits/sim.toml daddpg_jax/deploy/limits/ur3_cell.toml \\
        --episodes 200 --out docs/results/limits
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
import urllib.request

from daddpg_jax.analysis.engines import newcombe_paired_interval, paired_counts
from mjx_envs import episode_starts

PY = sys.executable
HERE = os.path.dirname(os.path.abspath(__file__))


def _best_test_success(run_dir: str) -> float:
    with open(os.path.join(run_dir, "metrics.csv")) as f:
        return max(float(r["test_success_rate"]) for r in csv.DictReader(f))


def _run(cmd: list, **kw) -> subprocess.CompletedProcess:
    print("$ " + " ".join(cmd), flush=True)
    return subprocess.run(cmd, check=True, text=True, capture_output=True, **kw)


def _evaluate(run_dir, limits, episodes, seed, speed_scale, tmp) -> dict:
    out = os.path.join(tmp, "eval.json")
    cmd = [PY, os.path.join(HERE, "evaluate.py"), run_dir, "--best", "--episodes",
           str(episodes), "--seed", str(seed), "--json", out, "--save-starts",
           os.path.join(tmp, "starts.npz")]
    if limits:
        cmd += ["--limits", limits, "--speed-scale", str(speed_scale)]
    _run(cmd)
    with open(out) as f:
        return json.load(f)


def _robot_client(policy, limits, episodes, seed, speed_scale, port, tmp,
                  starts: str | None = None) -> dict:
    serve = subprocess.Popen([PY, os.path.join(HERE, "serve.py"), policy, "--port", str(port)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        out = os.path.join(tmp, "client.json")
        for _ in range(100):  # the service is up once /health answers
            try:
                urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=1)
                break
            except OSError:
                time.sleep(0.3)
        _run([PY, os.path.join(HERE, "robot_client.py"), "--server",
              f"http://127.0.0.1:{port}", "--arms", "sim", "--fast", "--limits", limits,
              "--speed-scale", str(speed_scale), "--episodes", str(episodes), "--seed",
              str(seed), "--json", out] + (["--starts", starts] if starts else []))
        with open(out) as f:
            return json.load(f)
    finally:
        serve.terminate()
        serve.wait()


def _paired(starts: str, rc: dict) -> dict:
    """The paired comparison over the episodes both sides counted (the robot client excludes
    an episode with a missed deadline): robot client minus evaluation, its 95 % interval,
    and the episodes each side alone solved."""
    ev = episode_starts.load(starts).success
    rc_ok = rc["episode_success"]
    keep = [i for i, x in enumerate(rc_ok) if x is not None]
    counts = paired_counts([bool(rc_ok[i]) for i in keep], ev[keep])
    n = max(1, len(keep))
    return dict(paired=True, paired_episodes=len(keep), paired_counts=counts,
                paired_difference=(counts["first_only"] - counts["second_only"]) / n,
                paired_ci95=list(newcombe_paired_interval(counts["both"], counts["first_only"],
                                                          counts["second_only"],
                                                          counts["neither"])))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+", help="training run directories")
    p.add_argument("--limits", nargs="+", required=True, help="limits files")
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--speed-scale", type=float, default=1.0)
    p.add_argument("--port", type=int, default=8731)
    p.add_argument("--out", default="docs/results/limits")
    p.add_argument("--unpaired", action="store_true",
                   help="the robot client draws its own episodes (--seed) instead of playing "
                        "the evaluation's")
    args = p.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    for run_dir in args.runs:
        with open(os.path.join(run_dir, "config.json")) as f:
            env_over = json.load(f).get("env_overrides") or {}
        trained = env_over.get("robot_limits")
        penalty = float(env_over.get("intervention_penalty", 0.0))
        with tempfile.TemporaryDirectory() as tmp:
            policy = os.path.join(tmp, "policy.npz")
            _run([PY, os.path.join(HERE, "export.py"), run_dir, "--best", "--out", policy])
            for limits in args.limits:
                t0 = time.time()
                ev = _evaluate(run_dir, limits, args.episodes, args.seed, args.speed_scale, tmp)
                starts = None if args.unpaired else ev["starts"]
                rc = _robot_client(policy, limits, args.episodes, args.seed, args.speed_scale,
                                   args.port, tmp, starts)
                row = dict(run=os.path.basename(os.path.normpath(run_dir)),
                           trained_limits=trained, intervention_penalty=penalty,
                           limits=os.path.basename(limits),
                           speed_scale=args.speed_scale, episodes=args.episodes,
                           seed=args.seed, train_best_test_success=_best_test_success(run_dir),
                           evaluate_limits_success=ev["success_rate"],
                           evaluate_limits_ci95=ev.get("success_ci95"),
                           robot_client_success=rc["success_rate"],
                           robot_client_episodes_counted=rc.get("episodes"),
                           robot_client_interventions=rc.get("safety_counts"),
                           gate_refusals=rc.get("gate_refusals"),
                           wall_s=round(time.time() - t0, 1))
                row["difference"] = row["robot_client_success"] - row["evaluate_limits_success"]
                if starts:
                    row.update(_paired(starts, rc))
                name = (f"{row['run']}__{os.path.splitext(row['limits'])[0]}"
                        f"{'' if args.speed_scale == 1 else f'_x{args.speed_scale:g}'}.json")
                with open(os.path.join(args.out, name), "w") as f:
                    json.dump(row, f, indent=2)
                print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
