"""The Stable-Baselines3 comparison harness behind ``experiments/sb3/compare_sb3.py`` (which
holds its flags): SB3 DDPG + HerReplayBuffer through the
Gymnasium adapter against this project's trainer, each method in its own process, stopped at a
wall-clock budget or a target test success; results as JSON and a Markdown table. Settings and
measured results: docs/BENCHMARKS.md#stable-baselines3-side-by-side.
"""

from __future__ import annotations

import csv
import json
import os
import platform
import subprocess
import sys
import time
from types import SimpleNamespace

import numpy as np

from daddpg_jax.algo.config import TrainConfig, preset
from daddpg_jax.running.levels import reaches  # success-level test, float32 tolerance

METHODS = ("single", "daddpg", "sb3", "single_mt", "daddpg_mt")
DEFAULT_METHODS = ("single", "daddpg", "sb3")
XLA_ONE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
SB3_DIR = "sb3_ddpg_her"
WORKER_SCRIPT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "compare_sb3.py")
"""the script a method's worker process runs (with --worker METHOD)"""


class _Stop(Exception):
    pass


def _load() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


# ------------------------------------------------------------------------------ ours --------

def run_ours(args, method: str) -> dict:
    algo = method.removesuffix("_mt")
    # lazy: imports JAX, which only the worker process of one of our methods needs
    from daddpg_jax.running.runner import RunOptions, train

    cfg = TrainConfig(**preset(args.task)).replace(
        algo=algo, seed=args.seed, n_epochs=100_000, n_test_episodes=args.eval_episodes,
        eval_seed=args.eval_seed, physics="c", keep_checkpoints=1)
    if args.num_envs is not None:
        cfg = cfg.replace(num_envs=args.num_envs)
    if args.updates_per_cycle is not None:
        cfg = cfg.replace(n_batches=args.updates_per_cycle)
    if args.cycles_per_epoch is not None:
        cfg = cfg.replace(n_cycles=args.cycles_per_epoch)
    run_dir = os.path.join(args.out, f"ours_{method}")
    rows = []

    def on_epoch(row):
        rows.append(row)
        print(f"[ours/{algo}] env_steps {row['env_steps']:>7,}  wall {row['wall_time']:7.1f} s  "
              f"test_success {row['test_success_rate']:.3f}", flush=True)
        if not args.no_stop_at_target and reaches(row["test_success_rate"], args.target):
            raise _Stop

    try:
        train(cfg, RunOptions(run_dir, hooks=SimpleNamespace(epoch=on_epoch),
                              time_budget_s=args.time_budget, command=" ".join(sys.argv)))
    except _Stop:
        pass
    name = f"ours/{algo}" + (" (XLA multi-thread)" if method.endswith("_mt") else "")
    return dict(method=name, run_dir=os.path.abspath(run_dir),
                curve=[dict(env_steps=int(r["env_steps"]), wall_time=float(r["wall_time"]),
                            test_success_rate=float(r["test_success_rate"]),
                            test_arm_contact_rate=float(r["test_arm_contact_rate"])) for r in rows],
                settings=dict(num_envs=cfg.num_envs, batch_size=cfg.batch_size,
                              n_batches=cfg.n_batches, n_cycles=cfg.n_cycles, hidden=cfg.hidden,
                              eval_every_env_steps=cfg.n_cycles * cfg.num_envs * 50))


# ------------------------------------------------------------------------------ SB3 ---------

class GymEvaluator:
    """Deterministic episodes from fixed seeds, all envs stepped together and the policy queried
    once per step for the whole batch."""

    def __init__(self, env_id: str, episodes: int, seed: int):
        import gymnasium as gym  # lazy: an optional extra (the SB3 worker only)

        self.envs = [gym.make(env_id).unwrapped for _ in range(episodes)]
        self.seeds = [seed + i for i in range(episodes)]

    def __call__(self, predict) -> dict:
        obs = [e.reset(seed=s)[0] for e, s in zip(self.envs, self.seeds)]
        n = len(self.envs)
        contact = np.zeros(n, bool)
        done = False
        while not done:
            batch = {k: np.stack([o[k] for o in obs]) for k in obs[0]}
            actions = predict(batch)
            out = [e.step(a) for e, a in zip(self.envs, actions)]
            obs = [o[0] for o in out]
            contact |= np.array([o[4]["arm_contact"] > 0 for o in out])
            done = out[0][3]
        success = np.array([o[4]["is_success"] for o in out])
        return dict(test_success_rate=float(success.mean()),
                    test_arm_contact_rate=float(contact.mean()))


def run_sb3(args) -> dict:
    # lazy: gymnasium, torch and stable-baselines3 are optional extras, needed by the SB3 worker
    import gymnasium as gym
    import stable_baselines3
    import torch
    from stable_baselines3 import DDPG, HerReplayBuffer
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.noise import NormalActionNoise
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    import mjx_envs.gym_env as ge  # lazy: needs gymnasium, an optional extra

    torch.set_num_threads(args.torch_threads)
    env_id = ge.ENV_IDS[args.task]
    n_envs, train_freq, grad_steps = sb3_schedule(args)
    venv = DummyVecEnv([lambda: Monitor(gym.make(env_id)) for _ in range(n_envs)])
    venv = VecNormalize(venv, norm_obs=True, norm_reward=False, clip_obs=5.0, gamma=0.98)
    venv.seed(args.seed)
    n_act = venv.action_space.shape[0]
    model = DDPG(
        "MultiInputPolicy", venv, learning_rate=1e-3, buffer_size=1_000_000, learning_starts=100,
        batch_size=256, tau=0.005, gamma=0.98, train_freq=train_freq,
        gradient_steps=grad_steps,
        action_noise=NormalActionNoise(np.zeros(n_act), 0.2 * np.ones(n_act)),
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs=dict(n_sampled_goal=4, goal_selection_strategy="future"),
        policy_kwargs=dict(net_arch=[256, 256, 256]), seed=args.seed, device="cpu", verbose=0)
    evaluator = GymEvaluator(env_id, args.eval_episodes, args.eval_seed)
    eval_every = sb3_eval_every(args)
    out_dir = os.path.join(args.out, SB3_DIR)
    os.makedirs(out_dir, exist_ok=True)
    curve = []

    def predict(batch):
        nb = venv.normalize_obs(batch)
        return model.predict(nb, deterministic=True)[0]

    class Cb(BaseCallback):
        def _on_training_start(self):
            self.t0 = time.perf_counter()
            self.paused = 0.0
            self.next_eval = eval_every

        def _on_step(self) -> bool:
            if self.num_timesteps < self.next_eval:
                return True
            self.next_eval += eval_every
            t_eval = time.perf_counter()
            train_time = t_eval - self.t0 - self.paused
            m = evaluator(predict)
            self.paused += time.perf_counter() - t_eval
            row = dict(epoch=len(curve) + 1, env_steps=int(self.num_timesteps),
                       wall_time=round(train_time, 3), **m,
                       updates=int(model._n_updates))
            curve.append(row)
            print(f"[sb3] env_steps {row['env_steps']:>7,}  wall {train_time:7.1f} s  "
                  f"test_success {m['test_success_rate']:.3f}  updates {row['updates']}",
                  flush=True)
            if not args.no_stop_at_target and reaches(m["test_success_rate"], args.target):
                return False
            return train_time < args.time_budget

    model.learn(total_timesteps=10**9, callback=Cb())
    with open(os.path.join(out_dir, "metrics.csv"), "w", newline="") as f:
        cols = ["epoch", "env_steps", "wall_time", "test_success_rate", "test_arm_contact_rate",
                "updates"]
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        w.writerows(curve)
    return dict(method="sb3/ddpg+her", run_dir=os.path.abspath(out_dir),
                curve=[{k: r[k] for k in ("env_steps", "wall_time", "test_success_rate",
                                          "test_arm_contact_rate")} for r in curve],
                settings=dict(sb3=stable_baselines3.__version__, torch=torch.__version__,
                              torch_threads=torch.get_num_threads(), net_arch=[256, 256, 256],
                              batch_size=256, n_envs=n_envs, train_freq=list(train_freq),
                              gradient_steps=grad_steps,
                              tau=0.005, gamma=0.98, action_noise=0.2, learning_starts=100,
                              her=dict(n_sampled_goal=4, goal_selection_strategy="future"),
                              vec_normalize=dict(norm_obs=True, clip_obs=5.0),
                              eval_every_env_steps=eval_every))


def sb3_schedule(args):
    """(n_envs, train_freq, gradient_steps) of SB3.

    Without --num-envs: one env and --sb3-gradient-steps after every 50-step episode (20 = the
    replay ratio of our 2-env preset). With --num-envs N: N envs stepped together and, after
    every 50 steps of all of them (N x 50 transitions = one cycle of ours), as many gradient
    steps as ours does per cycle (--updates-per-cycle, default the preset's 40)."""
    if args.num_envs is None:
        return 1, (1, "episode"), args.sb3_gradient_steps
    updates = args.updates_per_cycle or preset(args.task)["n_batches"]
    return args.num_envs, (50, "step"), updates


def sb3_eval_every(args) -> int:
    """SB3's env steps between evaluations: --eval-every, or with --num-envs one epoch of ours."""
    if args.num_envs is None:
        return args.eval_every
    cycles = args.cycles_per_epoch or preset(args.task)["n_cycles"]
    return cycles * args.num_envs * 50


# ------------------------------------------------------------------------------ report ------

def summarize(res: dict, target: float) -> dict:
    curve = res["curve"]
    hit = next((r for r in curve if reaches(r["test_success_rate"], target)), None)
    best = max(curve, key=lambda r: r["test_success_rate"]) if curve else None
    last = curve[-1] if curve else None
    return dict(
        method=res["method"], reached=hit is not None,
        env_steps_to_target=hit["env_steps"] if hit else None,
        wall_to_target=hit["wall_time"] if hit else None,
        best_success=best["test_success_rate"] if best else None,
        best_at_env_steps=best["env_steps"] if best else None,
        best_at_wall=best["wall_time"] if best else None,
        total_env_steps=last["env_steps"] if last else 0,
        total_wall=last["wall_time"] if last else 0.0,
        env_steps_per_s=((last["env_steps"] / last["wall_time"])
                         if last and last["wall_time"] else None))


def table(summaries: list, target: float) -> str:
    lines = [f"| method | wall clock to {target:g} (s) | env steps to {target:g} | "
             "best test success (at env steps, s) | trained env steps / wall (s) | env steps/s |",
             "|---|---:|---:|---:|---:|---:|"]
    for s in summaries:
        w = f"{s['wall_to_target']:.1f}" if s["reached"] else "not reached"
        e = f"{s['env_steps_to_target']:,}" if s["reached"] else "—"
        b = (f"{s['best_success']:.2f} ({s['best_at_env_steps']:,}, {s['best_at_wall']:.0f} s)"
             if s["best_success"] is not None else "—")
        sps = f"{s['env_steps_per_s']:.0f}" if s["env_steps_per_s"] else "—"
        lines.append(f"| {s['method']} | {w} | {e} | {b} | {s['total_env_steps']:,} / "
                     f"{s['total_wall']:.0f} | {sps} |")
    ref = next((s for s in summaries if s["method"].startswith("sb3") and s["reached"]), None)
    if ref:
        lines.append("")
        for s in summaries:
            if s is not ref and s["reached"]:
                wall = ref["wall_to_target"] / s["wall_to_target"]
                steps = ref["env_steps_to_target"] / s["env_steps_to_target"]
                lines.append(f"- {s['method']}: {wall:.1f}x less wall clock and {steps:.1f}x "
                             f"fewer env steps to {target:g} than SB3")
    return "\n".join(lines)


# ------------------------------------------------------------------------------ processes ---

def run_worker(args) -> None:
    """Trains one method (--worker) in this process; writes OUT/result_<method>.json."""
    res = run_sb3(args) if args.worker == "sb3" else run_ours(args, args.worker)
    res["threads"] = (f"torch intra-op threads {args.torch_threads}" if args.worker == "sb3"
                      else "XLA_FLAGS=" + os.environ.get("XLA_FLAGS", "(unset)"))
    with open(os.path.join(args.out, f"result_{args.worker}.json"), "w") as f:
        json.dump(res, f, indent=2)


def compare(args, methods: list, argv: list) -> int:
    """Runs every method in its own worker process (the command line `argv` + --worker), then
    writes OUT/results.json and OUT/results.md and prints the table; the exit code."""
    machine = dict(platform=platform.platform(), processor=platform.machine(),
                   cpu_count=os.cpu_count(), python=platform.python_version(),
                   load_before=_load())
    print(f"machine: {machine}", flush=True)
    results = []
    for m in methods:
        cmd = [sys.executable, WORKER_SCRIPT, *argv, "--worker", m]
        t0 = time.perf_counter()
        env = dict(os.environ)
        if m in ("single", "daddpg"):
            env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " " + XLA_ONE_THREAD).strip()
        proc = subprocess.run(cmd, env=env)
        if proc.returncode != 0:
            print(f"error: method {m} failed (exit {proc.returncode})", file=sys.stderr)
            return 1
        with open(os.path.join(args.out, f"result_{m}.json")) as f:
            res = json.load(f)
        res["process_seconds"] = round(time.perf_counter() - t0, 1)
        res["load_after"] = _load()
        results.append(res)
    machine["load_after"] = _load()
    summaries = [summarize(r, args.target) for r in results]
    md = table(summaries, args.target)
    payload = dict(command="python experiments/sb3/compare_sb3.py " + " ".join(argv),
                   machine=machine, target=args.target, time_budget_s=args.time_budget,
                   eval_episodes=args.eval_episodes, summaries=summaries, results=results)
    with open(os.path.join(args.out, "results.json"), "w") as f:
        json.dump(payload, f, indent=2)
    with open(os.path.join(args.out, "results.md"), "w") as f:
        f.write(md + "\n")
    print()
    print(md)
    print(f"\nload average before {machine['load_before']}, after {machine['load_after']}")
    print(f"wrote {os.path.abspath(os.path.join(args.out, 'results.json'))}")
    return 0
