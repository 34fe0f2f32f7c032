"""Train two cooperating UR3 arms with DADDPG + HER (or a baseline variant).

Examples
  python experiments/run.py --task reach                       # CPU defaults, a few minutes
  python experiments/run.py --task reach --num-envs 2048       # the accelerator-sized run
  python experiments/run.py --task push --algo maddpg --her final --out runs/push_maddpg
  python experiments/run.py --resume runs/push_maddpg --epochs 200   # continue to 200 epochs
  python experiments/run.py --task reach --set gamma=0.95 --set hidden=64,64 --env team_scale=0.5
  python experiments/run.py --task pickup --demos 100          # + 100 scripted demonstrations

Outputs in RUN_DIR: config.json, metrics.csv, learning_curve.png, checkpoints/{epoch}.
The per-task preset (docs/TRAINING.md) scales batch size and updates per cycle with --num-envs
so that the replay ratio stays near the HER baselines'; --set overrides any field after it.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time



def build_parser():
    from daddpg_jax.running.overrides import field_docs as _field_docs
    from daddpg_jax.algo.config import TrainConfig
    from mjx_envs.core import TaskConfig
    from mjx_envs.tasks.push import ObjectTaskConfig

    tdocs, edocs = _field_docs(TrainConfig), _field_docs(TaskConfig)
    odocs = _field_docs(ObjectTaskConfig)
    tdef = {f.name: f.default for f in dataclasses.fields(TrainConfig)}
    edef = {f.name: f.default for f in dataclasses.fields(TaskConfig)}
    odef = {f.name: f.default for f in dataclasses.fields(ObjectTaskConfig) if f.name not in edef}
    epilog = ["training fields for --set KEY=VALUE (default; meaning):"]
    epilog += [f"  {k} ({tdef[k]!r}): {tdocs.get(k, '')}" for k in tdef]
    epilog += ["", "env fields for --env KEY=VALUE (reach default; meaning):"]
    epilog += [f"  {k} ({edef[k]!r}): {edocs.get(k, '')}" for k in edef]
    epilog += ["", "additional env fields of push, pickup and pot (push default; meaning):"]
    epilog += [f"  {k} ({odef[k]!r}): {odocs.get(k, '')}" for k in odef]
    p = argparse.ArgumentParser(
        prog="run.py", description=__doc__, epilog="\n".join(epilog),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", choices=["reach", "push", "pickup", "pot"], default=None,
                   help="task to train (default reach; taken from config.json with --resume)")
    p.add_argument("--num-envs", type=int, default=None,
                   help="parallel environments; the task preset scales batch size and updates per "
                        "cycle with it (default: the preset's, 2 on CPU)")
    p.add_argument("--epochs", type=int, default=None,
                   help="total epochs (an epoch = n_cycles cycles + evaluation); with --resume the "
                        "run continues until this many epochs are done (default: the task preset)")
    p.add_argument("--seed", type=int, default=None, help="training seed (default 0)")
    p.add_argument("--algo", choices=["daddpg", "maddpg", "ddpg", "single"], default=None,
                   help="daddpg: actors see both arms (the paper); maddpg: actors see their own arm, "
                        "critics both; ddpg: independent arms; single: one agent, 8-d action")
    p.add_argument("--her", choices=["future", "final", "none"], default=None,
                   help="hindsight relabelling strategy (future uses k=4: 80%% relabelled)")
    p.add_argument("--physics", choices=["auto", "mjx", "c"], default=None,
                   help="physics engine: auto = MJX on an accelerator, MuJoCo C engine on CPU")
    p.add_argument("--out", default=None,
                   help="run directory (default runs/<task>_<algo>_s<seed>_<time>)")
    p.add_argument("--resume", metavar="RUN_DIR", default=None,
                   help="continue the run in RUN_DIR from its latest checkpoint (its config.json "
                        "is reused; --epochs may raise the total)")
    p.add_argument("--save-buffer", action="store_true",
                   help="store the replay buffer in checkpoints (large; makes --resume bit-exact)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", default=[],
                   help="override any training field (listed below); repeatable")
    p.add_argument("--env", action="append", metavar="KEY=VALUE", default=[],
                   help="override any env field of the task's default_config() (listed below); repeatable")
    p.add_argument("--demos", type=int, default=None, metavar="N",
                   help="play N episodes of the task's scripted controller at the start and train "
                        "on them beside the replay, with a behaviour-cloning term (push, pickup, "
                        "pot; not in the paper; same as --set n_demos=N; default 0 = off; "
                        "docs/TRAINING.md#demonstrations)")
    p.add_argument("--time-budget", type=float, default=None, metavar="SECONDS",
                   help="stop after the epoch during which this much wall time has passed")
    p.add_argument("--no-progress", action="store_true", help="disable the progress bar")
    return p


def _env_overrides(items, task: str) -> dict:
    """--env KEY=VALUE items checked against the fields of the task's default_config()."""
    import mjx_envs
    from daddpg_jax.running.overrides import parse_overrides

    defaults = {f.name: getattr(mjx_envs.default_config(task), f.name)
                for f in dataclasses.fields(mjx_envs.default_config(task))}
    return parse_overrides(items, defaults, "--env")


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)

    from daddpg_jax.running import checkpoint as ckpt
    from daddpg_jax.running.overrides import parse_overrides as _kv
    from daddpg_jax.algo.config import TrainConfig, preset
    from daddpg_jax.running.runner import NonFiniteLoss, train
    import mjx_envs

    tdef = {f.name: f.default for f in dataclasses.fields(TrainConfig)}
    sets = _kv(args.set, tdef, "--set")
    if args.resume:
        run_dir = args.resume
        if not os.path.exists(os.path.join(run_dir, "config.json")):
            parser.error(f"--resume: {run_dir}/config.json not found")
        cfg, payload = ckpt.load_config(run_dir)
        env_over = {**payload.get("env_overrides", {}), **_env_overrides(args.env, cfg.task)}
        for name in ("task", "num_envs", "algo", "her", "physics", "seed"):
            v = getattr(args, name)
            if v is not None and v != getattr(cfg, name):
                parser.error(f"--resume: --{name.replace('_', '-')} differs from the run's "
                             f"config ({getattr(cfg, name)!r}); start a new run instead")
        over = dict(sets)
    else:
        task = args.task or "reach"
        env_over = _env_overrides(args.env, task)
        over = preset(task, args.num_envs)
        for name in ("algo", "her", "physics", "seed"):
            v = getattr(args, name)
            if v is not None:
                over[name] = v
        over.update(sets)
        try:
            cfg = TrainConfig(**over)
        except ValueError as e:
            parser.error(str(e))
        run_dir = args.out or os.path.join(
            "runs", f"{cfg.task}_{cfg.algo}_s{cfg.seed}_{time.strftime('%Y%m%d-%H%M%S')}")
        over = {}
    if args.epochs is not None:
        over["n_epochs"] = args.epochs
    if args.save_buffer:
        over["save_buffer"] = True
    if args.demos is not None:
        if args.resume and args.demos != cfg.n_demos:
            parser.error(f"--resume: --demos differs from the run's config ({cfg.n_demos}); "
                         "start a new run instead")
        over["n_demos"] = args.demos
    try:
        cfg = cfg.replace(**over)
    except ValueError as e:
        parser.error(str(e))
    if cfg.n_demos > 0:
        from mjx_envs.tasks import scripted

        if cfg.task not in scripted.POLICIES:
            parser.error(f"--demos: task {cfg.task!r} has no scripted controller "
                         f"(available: {', '.join(sorted(scripted.POLICIES))})")

    print(f"run dir: {os.path.abspath(run_dir)}")
    print(f"task {cfg.task}, algo {cfg.algo}, her {cfg.her}, num_envs {cfg.num_envs}, batch "
          f"{cfg.batch_size} x {cfg.n_batches} updates/cycle, {cfg.n_cycles} cycles/epoch, "
          f"{cfg.n_epochs} epochs", flush=True)
    if cfg.n_demos > 0:
        print(f"demonstrations: {cfg.n_demos} scripted episodes (not counted in env steps), "
              f"{cfg.demo_batch} demo transitions per update, bc_weight {cfg.bc_weight}, "
              f"q_filter {cfg.q_filter}", flush=True)
    total = cfg.n_epochs * cfg.n_cycles
    bar = progress = update_progress = None
    # Long cycles (many updates, e.g. --num-envs 2048 on a CPU) also move the bar during the
    # updates: 10 ticks per cycle once a cycle has >= 200 updates.
    update_tick = cfg.n_batches // 10 if cfg.n_batches >= 200 else 0
    if not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(total=total, unit="cycle", dynamic_ncols=True, desc=f"{cfg.task}/{cfg.algo}")
        t_last = [time.perf_counter()]
        partial = [0.0]  # fraction of the current cycle already shown by update ticks
        steps_per_cycle = cfg.num_envs * 50

        def progress(m):
            now = time.perf_counter()
            sps = steps_per_cycle / max(now - t_last[0], 1e-9)
            t_last[0] = now
            bar.update(max(1.0 - partial[0], 0.0))
            partial[0] = 0.0
            bar.set_postfix(train_success=f"{float(m['success']):.2f}",
                            steps_s=f"{sps:,.0f}", refresh=False)

        if update_tick:
            def update_progress(n):
                inc = update_tick / cfg.n_batches
                if partial[0] + inc < 1.0:
                    partial[0] += inc
                    bar.update(inc)

    def on_epoch(row):
        msg = (f"epoch {row['epoch']:4d}  env_steps {row['env_steps']:>10,}  "
               f"test_success {row['test_success_rate']:.3f}  "
               f"arm_contact {row['test_arm_contact_rate']:.3f}  "
               f"critic_loss {row['critic_loss']:.4f}  {row['env_steps_per_s']:,.0f} steps/s")
        if bar is not None:
            bar.n = row["epoch"] * cfg.n_cycles
            bar.refresh()
            bar.write(msg)
        else:
            print(msg, flush=True)

    try:
        res = train(cfg, run_dir, env_overrides=env_over, resume=bool(args.resume),
                    progress=progress, on_epoch=on_epoch, command=" ".join(sys.argv),
                    time_budget_s=args.time_budget, update_progress=update_progress,
                    update_tick=update_tick)
    except NonFiniteLoss as e:
        if bar is not None:
            bar.close()
        print(f"error: {e}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        if bar is not None:
            bar.close()
        print(f"\ninterrupted; resume with: python experiments/run.py --resume {run_dir}",
              file=sys.stderr)
        return 130
    if bar is not None:
        bar.close()
    print(res.summary())
    return 0


if __name__ == "__main__":
    sys.exit(main())
