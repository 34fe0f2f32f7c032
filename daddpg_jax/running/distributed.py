"""Several processes, one training run: JAX's multi-process runtime (``jax.distributed``).

Every process runs the same command (only ``--process-id`` differs) and owns its local devices;
the training mesh (daddpg_jax/algo/sharding.py) spans the devices of all processes, so the
shard_map collectives (gradient ``pmean``, normalizer ``psum``) cross processes and every
process holds the same replicated parameters. Process 0 alone writes config.json,
metrics.csv, the plot and the progress output; all processes save and restore the orbax
checkpoints together (each writes its own shards of the replay buffer).

Joining: ``join(coordinator, num_processes, process_id)`` (daddpg-train ``--coordinator
HOST:PORT --num-processes N --process-id I``), or with no flags the cluster variables that
``jax.distributed.initialize()`` reads (a SLURM job step, Open MPI), used only when they show
more than one process. On a CPU the processes exchange data through gloo (JAX's CPU collectives).
A process that cannot join within ``timeout`` seconds exits with a one-line error instead of
hanging (JAX itself would wait, then abort with a stack trace).

Single process (no flags, no cluster of more than one): nothing here runs a collective, and
every helper returns at once. The module imports JAX only inside its functions: daddpg-train
imports it before parsing its flags, and --help stays JAX-free.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import socket
import sys
import threading
from dataclasses import asdict, dataclass

import numpy as np

DEFAULT_TIMEOUT = 60.0
"""seconds a process waits to join the job (--distributed-timeout)"""

CLUSTER_SIZE_VARS = ("SLURM_STEP_NUM_TASKS", "OMPI_COMM_WORLD_SIZE")
"""environment variables whose value > 1 means this process is one of a multi-process job that
``jax.distributed.initialize()`` detects by itself: a SLURM job step (``srun``; a batch script
run without srun is one process, whatever ``SLURM_NTASKS`` says) and Open MPI's ``mpirun``"""

_MESSAGE_BYTES = 16384


class DistributedError(RuntimeError):
    """The process cannot join the job, or the processes disagree."""


@dataclass(frozen=True)
class Layout:
    """The processes of a job and their devices."""
    num_processes: int
    process_id: int
    process_devices: tuple      # local devices per process, by process id
    global_devices: int

    def to_dict(self) -> dict:
        """config.json's "distributed" entry (the process id left out: it differs)."""
        d = asdict(self)
        d.pop("process_id")
        d["process_devices"] = list(self.process_devices)
        return d


def cluster_size(environ=None) -> int:
    """The number of processes the cluster variables announce (1 when none does)."""
    environ = os.environ if environ is None else environ
    sizes = []
    for name in CLUSTER_SIZE_VARS:
        try:
            sizes.append(int(environ.get(name, "")))
        except ValueError:
            continue
    return max(sizes, default=1)


def parse_coordinator(address: str) -> tuple[str, int]:
    host, sep, port = str(address).rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise DistributedError(f"--coordinator {address!r}: expected HOST:PORT (e.g. "
                               "node0:12345), the address of process 0")
    return host, int(port)


def add_flags(parser) -> None:
    """daddpg-train's multi-process flags, as one argument group of `parser`."""
    g = parser.add_argument_group(
        "multi-process training (docs/SCALING.md; every process runs the same command, only "
        "--process-id differs; without these flags the cluster's variables are used when they "
        "show more than one process, e.g. SLURM's srun)")
    g.add_argument("--coordinator", metavar="HOST:PORT", default=None,
                   help="address of process 0, which runs the job's coordinator")
    g.add_argument("--num-processes", type=int, default=None, metavar="N",
                   help="number of processes in the job")
    g.add_argument("--process-id", type=int, default=None, metavar="I",
                   help="this process's id, 0 .. N-1 (process 0 writes the run's files)")
    g.add_argument("--distributed-timeout", type=float, default=DEFAULT_TIMEOUT,
                   metavar="SECONDS",
                   help="give up joining the job after this long, with an error "
                        f"(default {DEFAULT_TIMEOUT:g})")


def join_from_argv(argv=None) -> Layout | None:
    """`join` with the multi-process flags (`add_flags`) found in the command line `argv`
    (default sys.argv; the other arguments are left to the command's own parser)."""
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    add_flags(pre)
    args, _ = pre.parse_known_args(argv)
    return join(args.coordinator, args.num_processes, args.process_id,
                timeout=args.distributed_timeout)


def join(coordinator: str | None = None, num_processes: int | None = None,
         process_id: int | None = None, timeout: float = DEFAULT_TIMEOUT,
         environ=None, announce: bool = True) -> Layout | None:
    """Joins the multi-process job; returns its Layout, or None for a single-process run.

    Must run before anything else uses JAX. The three arguments go together; without them
    the cluster variables (CLUSTER_SIZE_VARS) decide: more than one process -> join with
    JAX's auto-detection, else single process."""
    given = [x is not None for x in (coordinator, num_processes, process_id)]
    if any(given) and not all(given):
        raise DistributedError("--coordinator, --num-processes and --process-id go together "
                               "(give all three, or none to read the cluster's variables)")
    if timeout <= 0:
        raise DistributedError(f"--distributed-timeout {timeout}: must be > 0 seconds")
    if not any(given):
        if cluster_size(environ) <= 1:
            return None
        where = "the cluster's coordinator"
    else:
        parse_coordinator(coordinator)
        if num_processes < 1 or not 0 <= process_id < num_processes:
            raise DistributedError(f"--process-id {process_id} with --num-processes "
                                   f"{num_processes}: need 0 <= process id < number of processes")
        if num_processes == 1:
            return None
        where = coordinator
    import jax  # lazy: daddpg-train imports this module before JAX (JAX-free --help)

    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    _initialize_or_exit(jax, coordinator, num_processes, process_id, timeout, where)
    layout = current_layout()
    if announce:
        n_local = layout.process_devices[layout.process_id]
        print(f"process {layout.process_id} of {layout.num_processes}, {n_local} local "
              f"device{'s' if n_local != 1 else ''}", flush=True)
    return layout


def _initialize_or_exit(jax, coordinator, num_processes, process_id, timeout, where) -> None:
    """jax.distributed.initialize under a watchdog: past `timeout` seconds the process prints
    one line and exits with status 2 (JAX's own timeout aborts the process with a stack
    trace, so the watchdog fires first)."""
    done = threading.Event()

    def watchdog():
        if done.wait(timeout):
            return
        print(f"error: {_join_failure(coordinator, num_processes, process_id, timeout, where)}",
              file=sys.stderr, flush=True)
        os._exit(2)

    threading.Thread(target=watchdog, daemon=True, name="distributed-join").start()
    try:
        jax.distributed.initialize(coordinator, num_processes, process_id,
                                   initialization_timeout=int(timeout) + 60)
    except Exception as e:   # noqa: BLE001 (XLA runtime errors: one line)
        done.set()
        raise DistributedError(f"could not join the job at {where}: {e}") from e
    done.set()


def _join_failure(coordinator, num_processes, process_id, timeout, where) -> str:
    if coordinator is not None and process_id != 0 and not _reachable(coordinator):
        return (f"no coordinator answered at {coordinator} within {timeout:g} s "
                "(--distributed-timeout): start process 0, which runs the coordinator, with "
                "the same --coordinator, and check the address and port")
    return (f"not all {num_processes or 'the'} processes joined the job at {where} within "
            f"{timeout:g} s (--distributed-timeout): start every process with the same "
            "--coordinator and --num-processes and its own --process-id")


def _reachable(coordinator: str) -> bool:
    host, port = parse_coordinator(coordinator)
    try:
        with socket.create_connection((host, port), timeout=2):
            return True
    except OSError:
        return False


def current_layout() -> Layout:
    import jax  # lazy: daddpg-train imports this module before JAX (JAX-free --help)

    counts = [0] * jax.process_count()
    for d in jax.devices():
        counts[d.process_index] += 1
    return Layout(num_processes=jax.process_count(), process_id=jax.process_index(),
                  process_devices=tuple(counts), global_devices=jax.device_count())


def is_multiprocess() -> bool:
    import jax  # lazy: daddpg-train imports this module before JAX (JAX-free --help)

    return jax.process_count() > 1


def is_primary() -> bool:
    """Process 0 (or the only process): the one that writes the run's files and output."""
    import jax  # lazy: daddpg-train imports this module before JAX (JAX-free --help)

    return jax.process_index() == 0


def barrier(name: str) -> None:
    """Waits until every process has reached the barrier `name` (no-op on one process)."""
    if is_multiprocess():
        from jax.experimental import multihost_utils  # lazy: as `import jax` above

        multihost_utils.sync_global_devices(name)


def from_primary(value):
    """Process 0's value of a JSON-serializable `value` on every process (itself on one)."""
    if not is_multiprocess():
        return value
    from jax.experimental import multihost_utils  # lazy: as `import jax` above

    raw = json.dumps(value).encode() if is_primary() else b""
    if len(raw) > _MESSAGE_BYTES:
        raise ValueError(f"from_primary: message of {len(raw)} bytes > {_MESSAGE_BYTES}")
    buf = np.zeros(_MESSAGE_BYTES + 4, np.uint8)
    buf[:4] = np.frombuffer(np.uint32(len(raw)).tobytes(), np.uint8)
    buf[4:4 + len(raw)] = np.frombuffer(raw, np.uint8)
    out = np.asarray(multihost_utils.broadcast_one_to_all(buf), np.uint8)
    n = int(np.frombuffer(out[:4].tobytes(), np.uint32)[0])
    return json.loads(out[4:4 + n].tobytes().decode())


def gather_ints(values) -> np.ndarray:
    """[num_processes, len(values)] int64: every process's `values` (one row on one process)."""
    row = np.asarray(values, np.int64).reshape(1, -1)
    if not is_multiprocess():
        return row
    from jax.experimental import multihost_utils  # lazy: as `import jax` above

    return np.asarray(multihost_utils.process_allgather(row[0])).reshape(-1, row.shape[1])


def config_digest(payload) -> str:
    """sha256 of a JSON-serializable configuration (keys sorted)."""
    text = json.dumps(payload, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def check_same_config(payload) -> None:
    """Raises DistributedError on every process when the processes' configurations differ."""
    if not is_multiprocess():
        return
    digest = config_digest(payload)
    words = np.frombuffer(bytes.fromhex(digest)[:16], np.uint32).astype(np.int64)
    rows = gather_ints(words)
    differ = [i for i in range(rows.shape[0]) if not np.array_equal(rows[i], rows[0])]
    if differ:
        raise DistributedError(
            f"the configuration of process(es) {', '.join(map(str, differ))} differs from "
            "process 0's (training fields, env overrides, run directory or resume): every "
            "process must run the same command, with only --process-id differing")


def agree_ok(ok: bool) -> list[int]:
    """The ids of the processes for which `ok` is False (every process gets the same list)."""
    rows = gather_ints([0 if ok else 1])
    return [i for i in range(rows.shape[0]) if rows[i, 0]]


def on_primary(fn, *args, errors=(Exception,)):
    """Runs fn(*args) on process 0, and raises on every process the error it raised (same
    type among `errors`, same message); returns fn's JSON-serializable result everywhere."""
    if not is_multiprocess():
        return fn(*args)
    result, err = None, None
    if is_primary():
        try:
            result = fn(*args)
        except errors as e:
            err = [type(e).__name__, str(e)]
    result, err = from_primary([result, err])
    if err is not None:
        by_name = {cls.__name__: cls for cls in errors}
        raise by_name.get(err[0], RuntimeError)(err[1])
    return result
