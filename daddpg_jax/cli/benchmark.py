"""Measure env and training throughput per task, engine and size; print a table, write JSON.

--mode env:   env-only physics and control steps/s and compile time (vmapped reset + scan),
              plus contacts per step for contact tasks (scripted episodes);
--mode train: the compiled train_epoch with the task preset for each num_envs (n_cycles
              reduced to --n-cycles for timing): env steps/s, updates/s, compile time, the
              rollout share of a cycle, CPU time per cycle, peak host RSS / device memory;
--mode all:   both.
Small sizes on CPU by default; pass --sizes for accelerator sizes.

Examples:
  python experiments/benchmark.py                                   # reach, C engine + MJX, CPU sizes
  python experiments/benchmark.py --mode train --physics c --sizes 2 8 32
  python experiments/benchmark.py --tasks push pickup pot --mode env --physics c --sizes 64
  python experiments/benchmark.py --mode all --physics mjx --sizes 1024 4096 --device gpu   # GPU
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time


CPU_SIZES = [1, 64, 256]
CPU_TRAIN_SIZES = [2, 16]


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", nargs="+", default=["reach"], help="tasks to measure (reach, push, pickup, pot)")
    p.add_argument("--physics", nargs="+", default=["c", "mjx"], choices=["c", "mjx"],
                   help="physics engines to measure")
    p.add_argument("--mode", choices=["env", "train", "all"], default="all",
                   help="env-only throughput, training throughput, or both (default)")
    p.add_argument("--sizes", nargs="+", type=int, default=None,
                   help=f"num_envs values (default: env {CPU_SIZES}, train {CPU_TRAIN_SIZES})")
    p.add_argument("--train-physics", nargs="+", default=None, choices=["c", "mjx"],
                   help="engines for --mode train/all (default: --physics; on a CPU only 'c', "
                        "since MJX training programs take minutes to compile there)")
    p.add_argument("--steps", type=int, default=50, help="control steps per timed env run (one episode)")
    p.add_argument("--repeats", type=int, default=3, help="timed runs per point (median reported)")
    p.add_argument("--n-cycles", type=int, default=2,
                   help="cycles per timed training epoch (the preset's n_cycles is reduced to this)")
    p.add_argument("--device", choices=["cpu", "gpu", "tpu"], default=None,
                   help="preset family for training (default: from jax.default_backend())")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", default=[],
                   help="override a TrainConfig field of the training preset (repeatable)")
    p.add_argument("--env", action="append", metavar="KEY=VALUE", default=[],
                   help="override an env field (repeatable), e.g. episode_length=10")
    p.add_argument("--contacts", choices=["auto", "on", "off"], default="auto",
                   help="contacts per step in env mode: auto = for tasks with contact pairs")
    p.add_argument("--contact-envs", type=int, default=8, help="scripted episodes for contact counts")
    p.add_argument("--profile", action="store_true",
                   help="with --mode train/all: also trace one epoch of the first task/engine/size "
                        "with jax.profiler and print the XLA op-time breakdown")
    p.add_argument("--out", default="benchmark.json", help="JSON file for the results")
    args = p.parse_args(argv)

    import jax

    import mjx_envs
    from daddpg_jax.analysis import benchmark as bm
    from daddpg_jax.algo.config import TrainConfig, preset
    from mjx_envs import schema, settings

    try:
        sets = schema.parse_overrides(TrainConfig, args.set, "--set")
        # fields of any task (the object tasks' config holds every field)
        env_over = schema.parse_overrides(type(settings.default_config("push")), args.env,
                                          "--env")
    except schema.ConfigError as e:
        p.error(str(e))
    backend = jax.default_backend()
    device = args.device or ("cpu" if backend == "cpu" else "gpu")
    machine = bm.machine_description()
    load0 = bm.load()
    print(f"machine: {machine}; load average (1 min) {load0:.2f}")
    env_sizes = args.sizes or CPU_SIZES
    train_sizes = args.sizes or CPU_TRAIN_SIZES
    train_physics = args.train_physics
    if train_physics is None:
        train_physics = list(args.physics)
        if backend == "cpu" and "c" in train_physics:
            train_physics = ["c"]
    env_rows, contact_rows, train_rows = [], [], []

    if args.mode in ("env", "all"):
        hdr = (f"{'task':8s} {'engine':6s} {'envs':>6s} {'control/s':>12s} {'physics/s':>12s} "
               f"{'compile s':>10s}")
        print("\n[env] env-only throughput (random actions)")
        print(hdr)
        print("-" * len(hdr))
        for task in args.tasks:
            for physics in args.physics:
                env = mjx_envs.make(task, physics=physics, **env_over)
                for n in env_sizes:
                    r = bm.env_throughput(env, n, n_steps=args.steps, repeats=args.repeats)
                    r["load"] = bm.load()
                    env_rows.append(r)
                    print(f"{task:8s} {physics:6s} {n:6d} {r['control_steps_per_s']:12,.0f} "
                          f"{r['physics_steps_per_s']:12,.0f} {r['compile_s']:10.1f}", flush=True)
                want = args.contacts == "on" or (
                    args.contacts == "auto" and bm._has_contacts(env.mj_model))
                if want:
                    c = bm.contacts_per_step(env, num_envs=args.contact_envs)
                    contact_rows.append(c)
                    print(f"{task:8s} {physics:6s} contacts/step over {args.contact_envs} scripted "
                          f"episodes: mean {c['contacts_mean']:.2f}, max {c['contacts_max']}", flush=True)

    if args.mode in ("train", "all"):
        print(f"\n[train] compiled train_epoch, {device} preset, n_cycles={args.n_cycles}"
              + (f", overrides {sets}" if sets else ""))
        hdr = (f"{'task':8s} {'engine':6s} {'envs':>6s} {'dev':>3s} {'batch':>6s} {'upd/cyc':>7s} "
               f"{'env st/s':>10s} {'upd/s':>8s} {'compile s':>9s} {'rollout%':>8s} "
               f"{'cpu s/cyc':>9s} {'RSS MB':>8s} {'dev MB':>8s}")
        print(hdr)
        print("-" * len(hdr))
        for task in args.tasks:
            for physics in train_physics:
                env = mjx_envs.make(task, physics=physics, **env_over)
                for n in train_sizes:
                    over = preset(task, n, episode_length=env.episode_length, device=device)
                    over.update(physics=physics, n_cycles=args.n_cycles)
                    over.update(sets)
                    cfg = TrainConfig(**over)
                    r = bm.train_throughput(env, cfg, repeats=max(1, min(args.repeats, 2)))
                    r["load"] = bm.load()
                    train_rows.append(r)
                    dev_mb = r.get("device_peak_mb")
                    print(f"{task:8s} {physics:6s} {n:6d} {r['num_devices']:3d} {r['batch_size']:6d} "
                          f"{r['n_batches']:7d} {r['env_steps_per_s']:10,.0f} {r['updates_per_s']:8.1f} "
                          f"{r['compile_s']:9.1f} {100 * r.get('rollout_share', float('nan')):7.0f}% "
                          f"{r['cpu_s_per_cycle']:9.2f} {r['host_peak_rss_mb']:8.0f} "
                          f"{'-' if dev_mb is None else f'{dev_mb:8.0f}':>8s}", flush=True)

    profile = None
    if args.profile and args.mode in ("train", "all"):
        import tempfile

        task, physics, n = args.tasks[0], train_physics[0], train_sizes[0]
        env = mjx_envs.make(task, physics=physics, **env_over)
        over = preset(task, n, episode_length=env.episode_length, device=device)
        over.update(physics=physics, n_cycles=args.n_cycles)
        over.update(sets)
        profile = bm.op_profile(env, TrainConfig(**over), tempfile.mkdtemp(prefix="daddpg_prof_"))
        profile.update(task=task, physics=physics, num_envs=n)
        print(f"\n[profile] {task} {physics} {n} envs: one epoch of {args.n_cycles} cycles, "
              f"{profile['wall_s']:.2f} s wall, {profile['total_ms']:.0f} ms of XLA op time")
        for name, ms, share, count in profile["ops"]:
            print(f"  {name:32s} {ms:9.1f} ms {100 * share:5.1f}% {count:7d} calls")

    out = {"machine": machine, "command": " ".join([os.path.basename(sys.executable)] + sys.argv),
           "time": time.strftime("%Y-%m-%d %H:%M:%S"), "load_start": load0, "load_end": bm.load(),
           "jax": jax.__version__, "devices": len(jax.devices()), "mode": args.mode,
           "results": env_rows, "contacts": contact_rows, "train": train_rows,
           "profile": profile,
           "train_settings": {"device_preset": device, "n_cycles": args.n_cycles,
                              "overrides": {k: list(v) if isinstance(v, tuple) else v
                                            for k, v in sets.items()},
                              "env_overrides": env_over}}
    with open(args.out, "w") as f:
        json.dump(out, f, indent=2, default=lambda o: list(o) if isinstance(o, tuple) else str(o))
    print(f"wrote {args.out}")
    return out


if __name__ == "__main__":
    main()
