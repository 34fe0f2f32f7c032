"""Measure env and training throughput per task, engine and size; print a table, write JSON.

--mode env:   env-only physics and control steps/s and compile time (vmapped reset + scan),
              plus contacts per step for contact tasks (scripted episodes);
--mode train: the compiled train_epoch with the task preset for each num_envs (n_cycles
              reduced to --n-cycles for timing): env steps/s, updates/s, compile time, the
              rollout share of a cycle, CPU time per cycle, peak host RSS / device memory;
--mode all:   both.
Small sizes on CPU by default; pass --sizes for accelerator sizes.

Examples:
  daddpg-benchmark                                  # reach, C engine + MJX, CPU sizes
  daddpg-benchmark --mode train --physics c --sizes 2 8 32
  daddpg-benchmark --tasks push pickup pot --mode env --physics c --sizes 64
  daddpg-benchmark --mode all --physics mjx --sizes 1024 4096 --device gpu   # GPU
(`python experiments/benchmark.py ...` is the same command.)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

from daddpg_jax.algo.config import DEVICES, TrainConfig, current_device, preset
from mjx_envs import schema, settings
from mjx_envs.settings import DEFAULT_TASK, ENGINES, TASKS

CPU_SIZES = [1, 64, 256]
CPU_TRAIN_SIZES = [2, 16]


def build_parser():
    p = argparse.ArgumentParser(prog="daddpg-benchmark", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", nargs="+", default=[DEFAULT_TASK], choices=TASKS,
                   help="tasks to measure")
    p.add_argument("--physics", nargs="+", default=sorted(ENGINES), choices=ENGINES,
                   help="physics engines to measure")
    p.add_argument("--mode", choices=["env", "train", "all"], default="all",
                   help="env-only throughput, training throughput, or both (default)")
    p.add_argument("--sizes", nargs="+", type=int, default=None,
                   help=f"num_envs values (default: env {CPU_SIZES}, train {CPU_TRAIN_SIZES})")
    p.add_argument("--train-physics", nargs="+", default=None, choices=ENGINES,
                   help="engines for --mode train/all (default: --physics; on a CPU only 'c', "
                        "since MJX training programs take minutes to compile there)")
    p.add_argument("--steps", type=int, default=50,
                   help="control steps per timed env run (one episode)")
    p.add_argument("--repeats", type=int, default=3, help="timed runs per point (median reported)")
    p.add_argument("--n-cycles", type=int, default=2,
                   help="cycles per timed training epoch (the preset's n_cycles is reduced to "
                        "this)")
    p.add_argument("--device", choices=DEVICES, default=None,
                   help="preset family for training (default: the device JAX runs on)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", default=[],
                   help="override a TrainConfig field of the training preset (repeatable)")
    p.add_argument("--env", action="append", metavar="KEY=VALUE", default=[],
                   help="override an env field (repeatable), e.g. episode_length=10")
    p.add_argument("--contacts", choices=["auto", "on", "off"], default="auto",
                   help="contacts per step in env mode: auto = for tasks with contact pairs")
    p.add_argument("--contact-envs", type=int, default=8,
                   help="scripted episodes for contact counts")
    p.add_argument("--profile", action="store_true",
                   help="with --mode train/all: also trace one epoch of the first "
                        "task/engine/size with jax.profiler and print the XLA op-time breakdown")
    p.add_argument("--out", default="benchmark.json", help="JSON file for the results")
    return p


def _table(hdr: str) -> None:
    print(hdr)
    print("-" * len(hdr))


def env_mode(args, env_over, sizes):
    """Env-only throughput rows and contact rows."""
    import mjx_envs
    from daddpg_jax.analysis import benchmark as bm

    env_rows, contact_rows = [], []
    print("\n[env] env-only throughput (random actions)")
    _table(f"{'task':8s} {'engine':6s} {'envs':>6s} {'control/s':>12s} {'physics/s':>12s} "
           f"{'compile s':>10s}")
    for task in args.tasks:
        for physics in args.physics:
            env = mjx_envs.make(task, physics=physics, **env_over)
            for n in sizes:
                r = bm.env_throughput(env, n, n_steps=args.steps, repeats=args.repeats)
                r["load"] = bm.load()
                env_rows.append(r)
                print(f"{task:8s} {physics:6s} {n:6d} {r['control_steps_per_s']:12,.0f} "
                      f"{r['physics_steps_per_s']:12,.0f} {r['compile_s']:10.1f}", flush=True)
            if args.contacts == "on" or (args.contacts == "auto"
                                         and bm._has_contacts(env.mj_model)):
                c = bm.contacts_per_step(env, num_envs=args.contact_envs)
                contact_rows.append(c)
                print(f"{task:8s} {physics:6s} contacts/step over {args.contact_envs} scripted "
                      f"episodes: mean {c['contacts_mean']:.2f}, max {c['contacts_max']}",
                      flush=True)
    return env_rows, contact_rows


def _train_config(env, task, physics, n, args, sets):
    over = preset(task, n, episode_length=env.episode_length, device=args.device)
    over.update(physics=physics, n_cycles=args.n_cycles)
    return TrainConfig(**{**over, **sets})


def train_mode(args, env_over, sets, sizes, train_physics):
    """Training throughput rows (the compiled train_epoch at each size)."""
    import mjx_envs
    from daddpg_jax.analysis import benchmark as bm

    rows = []
    print(f"\n[train] compiled train_epoch, {args.device or current_device()} preset, "
          f"n_cycles={args.n_cycles}" + (f", overrides {sets}" if sets else ""))
    _table(f"{'task':8s} {'engine':6s} {'envs':>6s} {'dev':>3s} {'batch':>6s} {'upd/cyc':>7s} "
           f"{'env st/s':>10s} {'upd/s':>8s} {'compile s':>9s} {'rollout%':>8s} "
           f"{'cpu s/cyc':>9s} {'RSS MB':>8s} {'dev MB':>8s}")
    for task in args.tasks:
        for physics in train_physics:
            env = mjx_envs.make(task, physics=physics, **env_over)
            for n in sizes:
                cfg = _train_config(env, task, physics, n, args, sets)
                r = bm.train_throughput(env, cfg, repeats=max(1, min(args.repeats, 2)))
                r["load"] = bm.load()
                rows.append(r)
                dev_mb = r.get("device_peak_mb")
                dev = "-" if dev_mb is None else f"{dev_mb:8.0f}"
                print(f"{task:8s} {physics:6s} {n:6d} {r['num_devices']:3d} "
                      f"{r['batch_size']:6d} {r['n_batches']:7d} {r['env_steps_per_s']:10,.0f} "
                      f"{r['updates_per_s']:8.1f} {r['compile_s']:9.1f} "
                      f"{100 * r.get('rollout_share', float('nan')):7.0f}% "
                      f"{r['cpu_s_per_cycle']:9.2f} {r['host_peak_rss_mb']:8.0f} {dev:>8s}",
                      flush=True)
    return rows


def profile_mode(args, env_over, sets, n, physics):
    """XLA op-time breakdown of one epoch of the first task at size n."""
    import tempfile

    import mjx_envs
    from daddpg_jax.analysis import benchmark as bm

    task = args.tasks[0]
    env = mjx_envs.make(task, physics=physics, **env_over)
    cfg = _train_config(env, task, physics, n, args, sets)
    profile = bm.op_profile(env, cfg, tempfile.mkdtemp(prefix="daddpg_prof_"))
    profile.update(task=task, physics=physics, num_envs=n)
    print(f"\n[profile] {task} {physics} {n} envs: one epoch of {args.n_cycles} cycles, "
          f"{profile['wall_s']:.2f} s wall, {profile['total_ms']:.0f} ms of XLA op time")
    for name, ms, share, count in profile["ops"]:
        print(f"  {name:32s} {ms:9.1f} ms {100 * share:5.1f}% {count:7d} calls")
    return profile


def run(argv=None) -> dict:
    """Parses the flags, measures, writes the JSON file and returns its content."""
    p = build_parser()
    args = p.parse_args(argv)
    try:
        sets = schema.parse_overrides(TrainConfig, args.set, "--set")
        # any task's field (the object tasks' config holds every field); make() checks the task
        env_over = schema.parse_overrides(settings.ObjectTaskConfig, args.env,
                                          "--env")
    except schema.ConfigError as e:
        p.error(str(e))

    import jax

    from daddpg_jax.analysis import benchmark as bm

    machine, load0 = bm.machine_description(), bm.load()
    print(f"machine: {machine}; load average (1 min) {load0:.2f}")
    train_physics = args.train_physics
    if train_physics is None:
        train_physics = list(args.physics)
        if jax.default_backend() == "cpu" and "c" in train_physics:
            train_physics = ["c"]
    env_rows, contact_rows, train_rows, profile = [], [], [], None
    if args.mode in ("env", "all"):
        env_rows, contact_rows = env_mode(args, env_over, args.sizes or CPU_SIZES)
    if args.mode in ("train", "all"):
        sizes = args.sizes or CPU_TRAIN_SIZES
        train_rows = train_mode(args, env_over, sets, sizes, train_physics)
        if args.profile:
            profile = profile_mode(args, env_over, sets, sizes[0], train_physics[0])
    out = {"machine": machine, "command": " ".join([os.path.basename(sys.executable)] + sys.argv),
           "time": time.strftime("%Y-%m-%d %H:%M:%S"), "load_start": load0, "load_end": bm.load(),
           "jax": jax.__version__, "devices": len(jax.devices()), "mode": args.mode,
           "results": env_rows, "contacts": contact_rows, "train": train_rows,
           "profile": profile,
           "train_settings": {"device_preset": args.device or current_device(),
                              "n_cycles": args.n_cycles, "overrides": schema.to_dict_values(sets),
                              "env_overrides": schema.to_dict_values(env_over)}}
    with open(args.out, "w") as f:
        json.dump(out, f, indent=2, default=str)
    print(f"wrote {args.out}")
    return out


def main(argv=None) -> int:
    run(argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
