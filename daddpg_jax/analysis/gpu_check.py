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
import statistics
import subprocess
import sys
import threading
import time
import traceback
from types import SimpleNamespace

from mjx_envs.settings import TASKS

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
SMOKE_TRAIN = dict(hidden=(32, 32), n_batches=4, batch_size=32, n_test_episodes=8, physics="c")
"""tiny trainer settings of --smoke (as tests/conftest.py's TINY)"""
SMOKE_EPISODE = 10
"""episode length of the envs in --smoke"""
DEFAULT_SHARE = 60.0
MIN_STAGE_S = 1.0
"""a stage with less time than this left in the budget is skipped"""
VERSIONS = ("jax", "jaxlib", "flax", "optax", "chex", "orbax-checkpoint", "numpy", "mujoco",
            "mujoco-mjx")
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
        "tool": "daddpg_jax.analysis.gpu_check",
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
    cmd = [sys.executable, "-m", "daddpg_jax.analysis.gpu_check", *argv, "--_child", stage,
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


# --------------------------------------------------------------- inside a stage -----------

class Recorder:
    """Appends JSON lines to the stage's records file (each flushed to disk at once)."""

    def __init__(self, path: str):
        self.path = path

    def __call__(self, kind: str, **fields) -> None:
        with open(self.path, "a") as f:
            f.write(json.dumps(dict(kind=kind, **fields), default=_jsonable) + "\n")
            f.flush()
            os.fsync(f.fileno())

    def row(self, key: str, row: dict) -> None:
        self("row", key=key, **row)


def _jsonable(x):
    try:
        return float(x)
    except (TypeError, ValueError):
        return str(x)


def _version(pkg: str) -> str | None:
    import importlib.metadata

    try:
        return importlib.metadata.version(pkg)
    except importlib.metadata.PackageNotFoundError:
        return None


def device_record() -> dict:
    import jax

    devs = jax.devices()
    out = {"device_kind": devs[0].device_kind, "device_count": len(devs),
           "backend": jax.default_backend(),
           "platform_version": getattr(devs[0].client, "platform_version", None)}
    out.update({p: _version(p) for p in VERSIONS})
    return out


def _one_line(e: BaseException, width: int = 300) -> str:
    lines = str(e).strip().splitlines()
    text = f"{type(e).__name__}: {lines[0]}" if lines else type(e).__name__
    return text if len(text) <= width else text[:width - 3] + "..."


def child_main(args) -> int:
    rec = Recorder(args._records)
    try:
        rec("device", **device_record())
        stage = args._child
        if stage == "env":
            stage_env(args, rec)
        elif stage == "train_epoch":
            stage_train(args, rec)
        else:
            stage_learn(args, rec, stage.removeprefix("learn_"))
        rec("done")
        return 0
    except Exception as e:  # noqa: BLE001 (recorded in the report; the next stage goes on)
        traceback.print_exc()
        rec("error", error=_one_line(e), traceback=traceback.format_exc(limit=8))
        return 1


def _env_overrides(args) -> dict:
    return {"episode_length": SMOKE_EPISODE} if args.smoke else {}


def _accel_device() -> str:
    from daddpg_jax.algo.config import current_device

    dev = current_device()
    return "gpu" if dev == "cpu" else dev


def stage_env(args, rec: Recorder) -> None:
    """Stage 1: every (size, task) point; a failed point is recorded and the next one runs."""
    import mjx_envs
    from daddpg_jax.running.runner import check_physics_backend

    points = [(n, t) for n in args.env_sizes for t in args.env_tasks]
    plan = {f"{t}/{n}": dict(task=t, physics=args.env_physics, num_envs=n) for n, t in points}
    rec("plan", rows=plan)
    envs = {}
    for n, task in points:
        key, base = f"{task}/{n}", plan[f"{task}/{n}"]
        if time.time() > args._deadline - MIN_STAGE_S:
            rec.row(key, dict(base, skipped="stage time cap"))
            continue
        try:
            check_physics_backend(args.env_physics, n)
            if task not in envs:
                envs[task] = mjx_envs.make(task, physics=args.env_physics,
                                           **_env_overrides(args))
            env_point(envs[task], n, args, lambda row, key=key, base=base:
                      rec.row(key, dict(base, **row)))
        except Exception as e:  # noqa: BLE001 (e.g. device out of memory: the next point)
            traceback.print_exc()
            rec.row(key, dict(base, error=_one_line(e)))


def env_point(env, n: int, args, emit) -> None:
    """Compile time, first call and steady-state steps/s of a scan of the vmapped env step."""
    import jax
    import jax.numpy as jnp

    from daddpg_jax.algo import acting

    T = int(args.env_steps)
    k_reset, k_act = jax.random.split(jax.random.PRNGKey(args.seed))
    t0 = time.perf_counter()
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(k_reset, n))
    actions = jax.random.uniform(k_act, (T, n, env.action_size), jnp.float32, -1, 1)
    jax.block_until_ready((states, actions))
    reset_s = time.perf_counter() - t0

    def run(s, xs):
        _, ok = acting.unroll(env, s, lambda s, a: a, xs=xs,
                              record=lambda s, a, s2: s2.metrics["physics_ok"].min())
        return ok.min()

    t0 = time.perf_counter()
    compiled = jax.jit(run).lower(states, actions).compile()
    row = {"steps": T, "compile_s": time.perf_counter() - t0, "reset_first_call_s": reset_s}
    emit(dict(row, note="compiled; timing"))
    t0 = time.perf_counter()
    jax.block_until_ready(compiled(states, actions))
    row["first_call_s"] = time.perf_counter() - t0
    times = []
    while len(times) < args.repeats and (not times or time.time() + times[-1] < args._deadline):
        t0 = time.perf_counter()
        ok = jax.block_until_ready(compiled(states, actions))
        times.append(time.perf_counter() - t0)
    call = statistics.median(times)
    row.update(call_s=call, timed_calls=len(times), env_steps_per_s=n * T / call,
               physics_steps_per_s=n * T * env.config.n_substeps / call,
               n_substeps=env.config.n_substeps, physics_ok=float(ok))
    row.update(_memory())
    emit(row)
    print(f"[env] {env.task_name} {env.physics} {n} envs: {row['env_steps_per_s']:,.0f} env "
          f"steps/s, compile {row['compile_s']:.1f} s", flush=True)


def _memory() -> dict:
    from daddpg_jax.analysis.benchmark import memory

    m = memory()
    return {k: m.get(k) for k in ("device_peak_mb", "host_peak_rss_mb")}


def train_config(args, task: str, num_envs: int | None, **extra):
    """The stage's TrainConfig: the accelerator preset (--smoke: the CPU preset, tiny)."""
    from daddpg_jax.algo.config import build_config

    if args.smoke:
        T = SMOKE_EPISODE
        return build_config(task, num_envs, device="cpu", episode_length=T,
                            **{**SMOKE_TRAIN, "buffer_size": 20 * T * (num_envs or 2), **extra})
    return build_config(task, num_envs, device=_accel_device(), **extra)


def stage_train(args, rec: Recorder) -> None:
    """Stage 2: compile, first epoch, timed epochs, then the rollout share if time is left."""
    import jax

    import mjx_envs
    from daddpg_jax.algo.train import make_train_fns
    from daddpg_jax.running.runner import check_physics_backend

    cfg = train_config(args, args.train_task, args.train_envs, n_cycles=args.train_cycles,
                       seed=args.seed)
    check_physics_backend(cfg.physics, cfg.num_envs)
    env = mjx_envs.make(cfg.task, physics=cfg.physics, **_env_overrides(args))
    T = env.episode_length
    row = dict(task=cfg.task, physics=env.physics, num_envs=cfg.num_envs,
               batch_size=cfg.batch_size, n_batches=cfg.n_batches, n_cycles=cfg.n_cycles,
               hidden=list(cfg.hidden), buffer_size=cfg.buffer_size)
    key = f"{cfg.task}/{cfg.num_envs}"
    rec("plan", rows={key: row})
    fns = make_train_fns(env, cfg)
    state = jax.block_until_ready(fns.init())
    t0 = time.perf_counter()
    epoch = fns.train_epoch.lower(state).compile()
    row.update(compile_s=time.perf_counter() - t0, num_devices=fns.num_devices, note="compiled")
    rec.row(key, row)
    t0 = time.perf_counter()
    state, m = jax.block_until_ready(epoch(state))
    row.update(first_epoch_s=time.perf_counter() - t0, note="first epoch done")
    rec.row(key, row)
    walls = []
    while len(walls) < args.repeats and time.time() + row["first_epoch_s"] < args._deadline:
        t0 = time.perf_counter()
        state, m = jax.block_until_ready(epoch(state))
        walls.append(time.perf_counter() - t0)
        wall = statistics.median(walls)
        row.update(epoch_s=wall, cycle_s=wall / cfg.n_cycles, timed_epochs=len(walls),
                   env_steps_per_s=cfg.n_cycles * cfg.num_envs * T / wall,
                   updates_per_s=cfg.n_cycles * cfg.n_batches / wall,
                   finite=not bool(jax.numpy.any(m["nonfinite"])), note="")
        row.update(_memory())
        rec.row(key, row)
    if not walls:
        row.update(note="no time left for a timed epoch")
        rec.row(key, row)
        return
    if time.time() + 2 * row["first_epoch_s"] < args._deadline:
        row.update(_rollout_time(fns, state, cfg.num_envs))
        row["rollout_share"] = row["rollout_s_per_cycle"] / row["cycle_s"]
        rec.row(key, row)
    print(f"[train_epoch] {cfg.task} {env.physics} {cfg.num_envs} envs: "
          f"{row['env_steps_per_s']:,.0f} env steps/s, {row['updates_per_s']:,.1f} updates/s, "
          f"compile {row['compile_s']:.1f} s", flush=True)


def _rollout_time(fns, state, n: int) -> dict:
    """The exploration rollout of one cycle alone (its own program): first call, median of 3."""
    import jax

    key = jax.random.PRNGKey(1)
    t0 = time.perf_counter()
    jax.block_until_ready(fns.rollout(state, key, n, True))
    first = time.perf_counter() - t0
    times = []
    for i in range(3):
        t0 = time.perf_counter()
        jax.block_until_ready(fns.rollout(state, jax.random.fold_in(key, i), n, True))
        times.append(time.perf_counter() - t0)
    return {"rollout_first_call_s": first, "rollout_s_per_cycle": statistics.median(times)}


class _Stop(Exception):
    pass


def stage_learn(args, rec: Recorder, task: str) -> None:
    """Stage 3 for one task: runner.train until the target or the stage's deadline; a record
    after every epoch (curve, time and env steps to the target, best success)."""
    from daddpg_jax.running.levels import reaches
    from daddpg_jax.running.runner import RunOptions, train

    t_process = PROCESS_START
    extra = dict(n_epochs=1, n_cycles=2) if args.smoke else {}
    cfg = train_config(args, task, args.learn_envs, keep_checkpoints=1, seed=args.seed, **extra)
    row = dict(task=task, physics=cfg.physics, num_envs=cfg.num_envs, batch_size=cfg.batch_size,
               n_batches=cfg.n_batches, n_cycles=cfg.n_cycles, n_epochs=cfg.n_epochs,
               epoch_env_steps=cfg.n_cycles * cfg.num_envs * (SMOKE_EPISODE if args.smoke else 50),
               n_test_episodes=cfg.n_test_episodes, epochs=0, reached=False, curve=[],
               note="compiling / first epoch")
    rec("plan", rows={task: row})
    rec.row(task, row)

    def on_epoch(r):
        s, steps, wall = float(r["test_success_rate"]), int(r["env_steps"]), float(r["wall_time"])
        row["curve"].append([steps, round(wall, 2), s])
        row.update(epochs=int(r["epoch"]), env_steps=steps, train_wall_s=wall,
                   process_s=time.time() - t_process, note="")
        if row.get("best_success") is None or s > row["best_success"]:
            row.update(best_success=s, env_steps_at_best=steps, wall_at_best_s=wall)
        if reaches(s, args.target) and not row["reached"]:
            row.update(reached=True, wall_to_target_s=wall, env_steps_to_target=steps,
                       process_to_target_s=time.time() - t_process)
        rec.row(task, row)
        print(f"[learn {task}] epoch {r['epoch']}: {steps:,} env steps, {wall:.1f} s, test "
              f"success {s:.2f}", flush=True)
        if row["reached"]:
            raise _Stop
        if time.time() >= args._deadline - MIN_STAGE_S:
            row["note"] = "stopped at the stage's time cap"
            raise _Stop

    try:
        train(cfg, RunOptions(os.path.join(args.out, "runs", task),
                              env_overrides=_env_overrides(args),
                              hooks=SimpleNamespace(epoch=on_epoch), force=True,
                              command="gpu_check",
                              time_budget_s=max(1.0, args._deadline - time.time())))
    except _Stop:
        pass
    except Exception as e:
        row.update(error=_one_line(e), note="")
        rec.row(task, row)
        raise
    if not row["reached"] and row["epochs"] >= cfg.n_epochs:
        row["note"] = "epoch budget done"
    rec.row(task, row)


if __name__ == "__main__":
    sys.exit(main())
