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
import functools
import json
import os
import sys
import time

from daddpg_jax.algo.config import DEVICES, TrainConfig, current_device, preset
from mjx_envs import schema, settings
from mjx_envs.registry import TASKS
from mjx_envs.settings import DEFAULT_TASK, ENGINES

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


def _log(line: str) -> None:
    print(line, flush=True)


def _train_config(env, task, physics, n, args, sets):
    over = preset(task, n, episode_length=env.episode_length, device=args.device)
    over.update(physics=physics, n_cycles=args.n_cycles)
    return TrainConfig(**{**over, **sets})


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

    # lazy: these import JAX, and --help and argument errors stay JAX-free
    import jax

    from daddpg_jax.analysis import benchmark

    machine, load0 = benchmark.machine_description(), benchmark.load()
    print(f"machine: {machine}; load average (1 min) {load0:.2f}")
    train_physics = args.train_physics
    if train_physics is None:
        train_physics = list(args.physics)
        if jax.default_backend() == "cpu" and "c" in train_physics:
            train_physics = ["c"]
    env_rows, contact_rows, train_rows, profile = [], [], [], None
    if args.mode in ("env", "all"):
        env_rows, contact_rows = benchmark.env_table(
            args.tasks, args.physics, args.sizes or CPU_SIZES, env_over, steps=args.steps,
            repeats=args.repeats, contacts=args.contacts, contact_envs=args.contact_envs,
            log=_log)
    if args.mode in ("train", "all"):
        sizes = args.sizes or CPU_TRAIN_SIZES
        print(f"\n[train] compiled train_epoch, {args.device or current_device()} preset, "
              f"n_cycles={args.n_cycles}" + (f", overrides {sets}" if sets else ""))
        make_cfg = functools.partial(_train_config, args=args, sets=sets)
        train_rows = benchmark.train_table(args.tasks, train_physics, sizes, env_over, make_cfg,
                                           repeats=max(1, min(args.repeats, 2)), log=_log)
        if args.profile:
            profile = benchmark.profile_table(args.tasks[0], train_physics[0], sizes[0],
                                              env_over, make_cfg, log=_log)
    out = {"machine": machine, "command": " ".join([os.path.basename(sys.executable)] + sys.argv),
           "time": time.strftime("%Y-%m-%d %H:%M:%S"), "load_start": load0,
           "load_end": benchmark.load(),
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
