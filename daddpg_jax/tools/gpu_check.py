"""One short check of a GPU machine, in stages (``experiments/gpu_check.sh``, ``make gpu-check``).

Stages, each in its own Python process under a time cap (a stage that fails or runs past its
cap is recorded as such, and the next stage starts):

1. ``env``: MJX env throughput, push and pickup at 1024, 4096 and 8192 envs: one jitted
   program = ``lax.scan`` of the vmapped ``env.step`` over 50 control steps of random actions
   from reset states; compile time (``lower().compile()``) apart from the steady state (median
   of timed calls after a first call).
2. ``train_epoch``: the compiled ``train_epoch`` of ``make_train_fns`` at the accelerator
   preset (reach, 4096 envs, 2 cycles per timed epoch): compile time, first epoch, env
   steps/s, updates/s, the rollout share of a cycle, device memory.
3. ``learn_reach``, ``learn_push``: ``runner.train`` at the accelerator preset until the
   test success reaches 0.9 or the stage's time runs out: wall time and env steps to 0.9 (or
   the best success reached), and the learning curve.

After every finished measurement (and every stage) ``gpu_check.json`` and ``gpu_check.md`` in
``--out`` are rewritten atomically, so a run cut off at any point still leaves its figures.
The whole check keeps to ``--budget`` seconds (default 280): each stage gets a share, and the
time a stage leaves unused goes to the next ones.

``experiments/gpu_check.sh`` runs this module from the checkout (PYTHONPATH); its own option
``--wheels DIR`` first installs the MuJoCo/MJX wheels in DIR offline into /tmp/site (for an
image with JAX but without MuJoCo).

``--smoke`` runs every stage at tiny sizes on a CPU (C engine, 2-8 envs, a tiny network and one
epoch of reach and push) in well under two minutes: it checks the tool, its figures mean
nothing.
"""

from __future__ import annotations

import argparse
import collections
import datetime
import json
import math
import os
import platform
import subprocess
import sys
import threading
import time

from mjx_envs.registry import TASKS

JSON_NAME = "gpu_check.json"
MD_NAME = "gpu_check.md"
FULL = dict(env_tasks=["push", "pickup"], env_sizes=[4096, 8192, 1024], env_physics="mjx",
            env_steps=50, repeats=3, train_task="reach", train_envs=4096, train_cycles=2,
            learn_tasks=["reach", "push"], learn_envs=None, budget=280.0)
"""full-size settings (a GPU); env sizes in order of priority: 4096 (the preset) first"""
FULL_SHARES = {"env": 95.0, "train_epoch": 50.0, "learn_reach": 50.0, "learn_push": 85.0}
SMOKE = dict(env_tasks=["push", "pickup"], env_sizes=[2, 8], env_physics="c", env_steps=10,
             repeats=2, train_task="reach", train_envs=4, train_cycles=2,
             learn_tasks=["reach", "push"], learn_envs=4, budget=110.0)
SMOKE_SHARES = {"env": 30.0, "train_epoch": 25.0, "learn_reach": 25.0, "learn_push": 30.0}
DEFAULT_SHARE = 60.0
MIN_STAGE_S = 1.0
"""a stage with less time than this left in the budget is skipped"""
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PROCESS_START = time.time()
"""about when this process started (before JAX was imported)"""


# ------------------------------------------------------------------------- flags ----------

def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="gpu_check", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="runs/gpu_check",
                   help="output directory: gpu_check.json, gpu_check.md, logs/, runs/")
    p.add_argument("--smoke", action="store_true",
                   help="every stage at tiny sizes on a CPU (checks the tool only)")
    p.add_argument("--budget", type=float, default=None,
                   help="seconds for the whole check (default 280; --smoke 110)")
    p.add_argument("--stage-seconds", action="append", default=[], metavar="STAGE=S",
                   help="share of the budget of a stage (repeatable; defaults: env 95, "
                        "train_epoch 50, learn_reach 50, learn_push 85)")
    p.add_argument("--stages", nargs="+", default=None,
                   help="run only these stages (env, train_epoch, learn_TASK)")
    p.add_argument("--env-tasks", nargs="+", choices=TASKS, default=None)
    p.add_argument("--env-sizes", nargs="+", type=int, default=None,
                   help="num_envs of stage 1, measured in this order")
    p.add_argument("--env-physics", choices=("mjx", "c"), default=None)
    p.add_argument("--env-steps", type=int, default=None, help="control steps per timed call")
    p.add_argument("--repeats", type=int, default=None, help="timed calls / epochs per point")
    p.add_argument("--train-task", choices=TASKS, default=None)
    p.add_argument("--train-envs", type=int, default=None)
    p.add_argument("--train-cycles", type=int, default=None, help="cycles per timed epoch")
    p.add_argument("--learn-tasks", nargs="+", choices=TASKS, default=None)
    p.add_argument("--learn-envs", type=int, default=None,
                   help="num_envs of stage 3 (default: the preset's, 4096)")
    p.add_argument("--target", type=float, default=0.9, help="test success to reach")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--_child", default=None, help=argparse.SUPPRESS)
    p.add_argument("--_deadline", type=float, default=None, help=argparse.SUPPRESS)
    p.add_argument("--_records", default=None, help=argparse.SUPPRESS)
    return p


def parse_args(argv) -> argparse.Namespace:
    p = build_parser()
    args = p.parse_args(argv)
    for k, v in (SMOKE if args.smoke else FULL).items():
        if getattr(args, k) is None:
            setattr(args, k, v)
    shares = dict(SMOKE_SHARES if args.smoke else FULL_SHARES)
    for item in args.stage_seconds:
        name, _, value = item.partition("=")
        try:
            shares[name.strip()] = float(value)
        except ValueError:
            p.error(f"--stage-seconds expects STAGE=SECONDS, got {item!r}")
    args.shares = shares
    known = all_stages(args)
    if args.stages is None:
        args.stages = known
    bad = [s for s in args.stages if s not in known]
    if bad:
        p.error(f"unknown stage(s) {bad}; known: {known}")
    args.stages = [s for s in known if s in args.stages]
    return args


def all_stages(args) -> list[str]:
    return ["env", "train_epoch"] + [f"learn_{t}" for t in args.learn_tasks]


# ------------------------------------------------------------------- the report -----------

def git_revision() -> str | None:
    """HEAD of the checkout (+ '-dirty' with uncommitted changes to tracked files), or None."""
    try:
        rev = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=ROOT,
                             capture_output=True, text=True, timeout=10)
        if rev.returncode != 0 or not rev.stdout.strip():
            return None
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=ROOT, capture_output=True, text=True, timeout=10)
        return rev.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


def new_report(args, argv) -> dict:
    return {
        "tool": "daddpg_jax.tools.gpu_check",
        "command": " ".join(["gpu_check"] + list(argv)),
        "smoke": args.smoke,
        "started": _now(), "updated": _now(), "finished": None,
        "budget_s": args.budget, "target": args.target,
        "git_revision": git_revision(),
        "host": {"cpu_count": os.cpu_count(), "machine": platform.machine(),
                 "python": platform.python_version(),
                 "jax_compilation_cache_dir": os.environ.get("JAX_COMPILATION_CACHE_DIR"),
                 "xla_flags": os.environ.get("XLA_FLAGS")},
        "device": None,
        "stages": {s: {"status": "pending", "rows": []} for s in args.stages},
    }


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def _write_atomic(path: str, text: str) -> None:
    tmp = f"{path}.tmp"
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def write_report(out_dir: str, report: dict) -> None:
    """gpu_check.json and gpu_check.md, each replaced whole."""
    report["updated"] = _now()
    _write_atomic(os.path.join(out_dir, JSON_NAME),
                  json.dumps(report, indent=2, default=str) + "\n")
    _write_atomic(os.path.join(out_dir, MD_NAME), markdown(report))


def _fmt(x, spec: str = ",.0f", none: str = "—") -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return none
    return format(x, spec)


def _row_note(r: dict) -> str:
    if r.get("error"):
        return f"error: {r['error']}"
    if r.get("skipped"):
        return f"not run: {r['skipped']}"
    return r.get("note", "")


def markdown(report: dict) -> str:
    """The report as markdown: header, one table per stage, the stages' states."""
    dev = report.get("device") or {}
    lines = ["# GPU check" + (" (smoke run: tiny sizes on a CPU, figures mean nothing)"
                              if report.get("smoke") else ""), "",
             f"- device: {dev.get('device_kind', '?')} × {dev.get('device_count', '?')} "
             f"(backend {dev.get('backend', '?')}); jax {dev.get('jax', '?')}, "
             f"jaxlib {dev.get('jaxlib', '?')}, mujoco {dev.get('mujoco', '?')}, "
             f"mujoco-mjx {dev.get('mujoco-mjx', '?')}",
             f"- git {report.get('git_revision') or '?'}; started {report.get('started')}, "
             f"updated {report.get('updated')}; budget {report.get('budget_s'):.0f} s",
             f"- command: `{report.get('command')}`", "",
             "| stage | status | cap (s) | wall (s) | note |", "|---|---|---:|---:|---|"]
    for name, st in report["stages"].items():
        lines.append(f"| {name} | {st['status']} | {_fmt(st.get('cap_s'), '.0f')} | "
                     f"{_fmt(st.get('wall_s'), '.1f')} | {st.get('error') or ''} |")
    stages = report["stages"]
    if "env" in stages:
        lines += _md_env(stages["env"]["rows"])
    preset = "tiny settings, --smoke" if report.get("smoke") else "accelerator preset"
    if "train_epoch" in stages:
        lines += _md_train(stages["train_epoch"]["rows"], preset)
    learn = [s for s in stages if s.startswith("learn_")]
    if learn:
        lines += _md_learn([r for s in learn for r in stages[s]["rows"]],
                           report.get("target", 0.9), preset)
    return "\n".join(lines) + "\n"


def _md_env(rows: list) -> list:
    out = ["", "## 1. Env throughput (vmapped step in a scan of random actions)", "",
           "| task | engine | envs | env steps/s | physics steps/s | compile (s) | first call (s) "
           "| call (s) | note |", "|---|---|---:|---:|---:|---:|---:|---:|---|"]
    for r in sorted(rows, key=lambda r: (r.get("task", ""), r.get("num_envs", 0))):
        out.append(f"| {r.get('task')} | {r.get('physics')} | {r.get('num_envs')} | "
                   f"{_fmt(r.get('env_steps_per_s'))} | {_fmt(r.get('physics_steps_per_s'))} | "
                   f"{_fmt(r.get('compile_s'), '.1f')} | {_fmt(r.get('first_call_s'), '.2f')} | "
                   f"{_fmt(r.get('call_s'), '.3f')} | {_row_note(r)} |")
    return out


def _md_train(rows: list, preset: str) -> list:
    out = ["", f"## 2. train_epoch ({preset})", "",
           "| task | engine | envs | batch × updates/cycle | cycles | env steps/s | updates/s | "
           "compile (s) | first epoch (s) | epoch (s) | rollout share | device peak (MB) | note |",
           "|---|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        share = r.get("rollout_share")
        share = "—" if share is None else f"{100 * share:.0f} %"
        out.append(f"| {r.get('task')} | {r.get('physics')} | {r.get('num_envs')} | "
                   f"{r.get('batch_size')} × {r.get('n_batches')} | {r.get('n_cycles')} | "
                   f"{_fmt(r.get('env_steps_per_s'))} | {_fmt(r.get('updates_per_s'), ',.1f')} | "
                   f"{_fmt(r.get('compile_s'), '.1f')} | {_fmt(r.get('first_epoch_s'), '.1f')} | "
                   f"{_fmt(r.get('epoch_s'), '.2f')} | "
                   f"{share} | "
                   f"{_fmt(r.get('device_peak_mb'))} | {_row_note(r)} |")
    return out


def _md_learn(rows: list, target: float, preset: str) -> list:
    out = ["", f"## 3. Training to {target:g} test success ({preset})", "",
           f"| task | envs | batch × updates/cycle | cycles/epoch | reached {target:g} | "
           f"wall to {target:g} (s) | env steps to {target:g} | best success | env steps at "
           "best | epochs | training wall (s) | process (s) | note |",
           "|---|---:|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        reached = r.get("reached")
        out.append(f"| {r.get('task')} | {r.get('num_envs')} | {r.get('batch_size')} × "
                   f"{r.get('n_batches')} | {r.get('n_cycles')} | "
                   f"{'—' if reached is None else ('yes' if reached else 'no')} | "
                   f"{_fmt(r.get('wall_to_target_s'), '.1f')} | "
                   f"{_fmt(r.get('env_steps_to_target'))} | {_fmt(r.get('best_success'), '.2f')} "
                   f"| {_fmt(r.get('env_steps_at_best'))} | {r.get('epochs', 0)} | "
                   f"{_fmt(r.get('train_wall_s'), '.1f')} | {_fmt(r.get('process_s'), '.1f')} | "
                   f"{_row_note(r)} |")
    return out


# ---------------------------------------------------------------- running stages ----------

def read_records(path: str) -> list[dict]:
    """The child's JSON lines; a line cut short by a kill is left out."""
    if not os.path.exists(path):
        return []
    out = []
    with open(path) as f:
        for line in f:
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    return out


def merge_records(report: dict, stage: str, records: list[dict]) -> None:
    """Folds the child's records into the report: rows by key (a later record of a key
    replaces the earlier one), planned rows not measured as 'not run', device and errors."""
    st = report["stages"][stage]
    rows: dict = {}
    for rec in records:
        kind = rec.get("kind")
        if kind == "device":
            report["device"] = report["device"] or {k: v for k, v in rec.items() if k != "kind"}
        elif kind == "plan":
            for key, base in rec["rows"].items():
                rows.setdefault(key, dict(base, key=key, skipped="stage ended first"))
        elif kind == "row":
            rows[rec["key"]] = {k: v for k, v in rec.items() if k != "kind"}
        elif kind == "error":
            st["error"] = rec["error"]
            st["traceback"] = rec.get("traceback")
        elif kind == "done":
            st["done"] = True
    st["rows"] = list(rows.values())


def _forward(pipe, log, tail: collections.deque) -> None:
    """Copies the child's output to ours and to its log file, keeping the last lines."""
    for raw in iter(pipe.readline, b""):
        line = raw.decode(errors="replace")
        sys.stdout.write(line)
        sys.stdout.flush()
        log.write(line)
        log.flush()
        tail.append(line.rstrip())


def run_stage(argv, args, stage: str, deadline: float, report: dict) -> None:
    """Runs one stage in a child process until it ends or the deadline passes (then it is
    killed), rewriting the report whenever the child has written a record."""
    out = args.out
    records = os.path.join(out, "logs", f"{stage}.jsonl")
    if os.path.exists(records):
        os.remove(records)
    st = report["stages"][stage]
    st.update(status="running", cap_s=round(deadline - time.time(), 1), started=_now())
    write_report(out, report)
    cmd = [sys.executable, "-m", "daddpg_jax.tools.gpu_check", *argv, "--_child", stage,
           "--_deadline", repr(deadline), "--_records", records]
    print(f"\n=== gpu_check stage {stage} (cap {st['cap_s']:.0f} s) ===", flush=True)
    t0 = time.time()
    tail: collections.deque = collections.deque(maxlen=15)
    with open(os.path.join(out, "logs", f"{stage}.log"), "w") as log:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        reader = threading.Thread(target=_forward, args=(proc.stdout, log, tail), daemon=True)
        reader.start()
        size, killed = -1, False
        while proc.poll() is None:
            if time.time() >= deadline:
                killed = True
                proc.terminate()
                try:
                    proc.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
                break
            time.sleep(0.5)
            new = os.path.getsize(records) if os.path.exists(records) else -1
            if new != size:
                size = new
                merge_records(report, stage, read_records(records))
                write_report(out, report)
        reader.join(timeout=5)
    merge_records(report, stage, read_records(records))
    st["wall_s"] = round(time.time() - t0, 2)
    _set_status(st, proc.returncode, killed, tail)
    write_report(out, report)


def _set_status(st: dict, returncode: int, killed: bool, tail) -> None:
    rows = st["rows"]
    if killed:
        st["status"] = "timeout"
        st["error"] = (st.get("error") or
                       f"stopped at the stage's time cap ({_fmt(st.get('cap_s'), '.0f')} s)")
    elif returncode != 0 or st.get("error") or not st.get("done"):
        st["status"] = "error"
        if not st.get("error"):
            st["error"] = f"exit code {returncode}: " + " / ".join(list(tail)[-5:])
    elif rows and all(r.get("error") for r in rows):
        st["status"] = "error"
        st["error"] = "every measurement failed"
    elif not rows or any(r.get("error") or r.get("skipped") for r in rows):
        st["status"] = "partial"
    else:
        st["status"] = "ok"


def main(argv=None) -> int:
    """Runs the check (or, with the hidden --_child, one stage of it). Returns 0 when no stage
    failed (stages stopped by their time cap count as done), else 1."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parse_args(argv)
    if args._child:
        return child_main(args)
    os.makedirs(os.path.join(args.out, "logs"), exist_ok=True)
    report = new_report(args, argv)
    write_report(args.out, report)
    t0 = time.time()
    end, planned = t0 + args.budget, t0
    for stage in args.stages:
        planned += args.shares.get(stage, DEFAULT_SHARE)
        deadline = min(planned, end)
        if deadline - time.time() < MIN_STAGE_S:
            report["stages"][stage].update(status="skipped", error="no time left in the budget")
            write_report(args.out, report)
            continue
        run_stage(argv, args, stage, deadline, report)
    report["finished"] = _now()
    report["wall_s"] = round(time.time() - t0, 1)
    write_report(args.out, report)
    print("\n" + markdown(report), flush=True)
    print(f"wrote {os.path.join(args.out, JSON_NAME)} and {os.path.join(args.out, MD_NAME)}")
    return 1 if any(s["status"] == "error" for s in report["stages"].values()) else 0


def child_main(args) -> int:
    """One stage, in the child process that run_stage started (--_child)."""
    # lazy: the stages import JAX; the parent process that schedules them stays JAX-free
    from daddpg_jax.tools import gpu_check_stages

    return gpu_check_stages.run(args, PROCESS_START, MIN_STAGE_S)


if __name__ == "__main__":
    sys.exit(main())
