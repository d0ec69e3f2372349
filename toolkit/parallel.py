"""Independent tasks on one interface: in this process, a local process pool, or a Dask cluster.

:func:`run_tasks` calls ``fn(shared, payload)`` for every payload and yields an
:class:`Outcome` per task as tasks finish.  Where they run is the caller's choice:

``jobs=1`` (no scheduler)
    In this process, in order.  Nothing to start; the right choice where a task takes
    milliseconds (the start of a worker process costs about 2 s, benchmarks/README.md).
``jobs=N``
    A pool of N worker processes started here (``spawn``, one BLAS thread each).  Each worker
    holds one task at a time, so when a worker dies (a crash in native code, the OOM killer, a
    ``kill -9``) the master knows the one task it lost: that task is started again on a fresh
    worker, up to ``retries`` more times, and its :attr:`Outcome.attempts` says so.  Other tasks
    are not touched.
``scheduler="local"`` or ``scheduler="tcp://host:8786"``
    dask.distributed (``pip install tendonkit[cluster]``): a :class:`distributed.LocalCluster`
    of ``jobs`` single-threaded process workers, or the cluster at that address.  ``shared`` is
    scattered to every worker once.  When a worker dies the scheduler moves its task to another
    worker (``distributed.scheduler.allowed-failures``, set to ``retries`` for a local cluster);
    the attempts are read from the scheduler's count of workers that died holding the task.

An exception raised by ``fn`` is not retried (it would raise again): it becomes the outcome's
``error`` (``"Type: message"``) and the other tasks go on.  Results do not depend on the engine
or the number of workers as long as ``fn`` does not: every random choice belongs in the
payload (a seed per task), never in the worker.

Examples
--------
>>> outs = sorted(run_tasks(pow_task, [2, 3], shared=10), key=lambda o: o.index)
>>> [o.value for o in outs], outs[0].attempts
([100, 1000], 1)
"""

from __future__ import annotations

import contextlib
import hashlib
import multiprocessing
import os
import pickle
import re
import signal
import socket
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from typing import Any

from .errors import OptionError, SimulationError, raise_if

__all__ = [
    "LOST",
    "Outcome",
    "dask_problems",
    "default_jobs",
    "dumps",
    "engine_name",
    "map_tasks",
    "pow_task",
    "run_tasks",
    "scheduler_problems",
    "task_problems",
    "worker_id",
]

#: Retries of a task whose worker died, after the first attempt.
RETRIES = 2
#: How an outcome's ``error`` starts when the engine lost the task (its worker died, or it ran
#: past the timeout) rather than the task failing: running it again may succeed.
WORKER_DIED, TIMEOUT = "WorkerDied", "Timeout"
LOST = (WORKER_DIED, TIMEOUT)


@dataclass(frozen=True)
class Outcome:
    """What one task gave.

    Attributes
    ----------
    index : int
        Position of the task's payload.
    value : object
        ``fn``'s return value (None when it raised or its workers kept dying).
    error : str or None
        ``"Type: message"`` of the exception ``fn`` raised, or why the task was given up.
    attempts : int
        Starts of the task: 1 unless a worker died holding it.
    worker : str
        ``host:pid`` of the process that ran it.
    seconds : float
        Wall time of the call in its worker.
    """

    index: int
    value: Any = None
    error: str | None = None
    attempts: int = 1
    worker: str = ""
    seconds: float = 0.0


def pow_task(shared: int, payload: int) -> int:
    """``payload ** (shared // 10 + 1)``: a picklable task for examples and tests."""
    return int(payload) ** (int(shared) // 10 + 1)


def worker_id() -> str:
    """``host:pid`` of this process."""
    return f"{socket.gethostname()}:{os.getpid()}"


def engine_name(jobs: int | None, scheduler: str | None) -> str:
    """What :func:`run_tasks` will use: ``serial``, ``processes`` or ``dask``."""
    if scheduler:
        return "dask"
    return "processes" if (jobs or default_jobs()) > 1 else "serial"


def default_jobs() -> int:
    """The cores this process may use."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # macOS, Windows
        return max(os.cpu_count() or 1, 1)


_ONE_THREAD = False


def _one_thread() -> None:
    """One BLAS/OpenMP thread in this worker (N workers on N cores must not oversubscribe)."""
    global _ONE_THREAD
    if not _ONE_THREAD:
        # lazy: heavy (threadpoolctl scans the loaded libraries)
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1)
        _ONE_THREAD = True


def _call(
    fn: Callable[[Any, Any], Any], shared: Any, payload: Any
) -> tuple[Any, str | None, float]:
    t0 = time.perf_counter()
    try:
        value, error = fn(shared, payload), None
    except Exception as exc:  # the task's failure is its outcome, never the campaign's
        value, error = None, f"{type(exc).__name__}: {exc}".strip()
        if os.environ.get("TENDONKIT_TASK_TRACEBACK"):
            error += "\n" + traceback.format_exc()
    return value, error, time.perf_counter() - t0


def dumps(obj: Any) -> bytes:
    """``obj`` as bytes for a worker: pickle, or cloudpickle (installed with dask) for closures
    and local classes; PicklingError when neither can."""
    try:
        return pickle.dumps(obj)
    except (pickle.PicklingError, AttributeError, TypeError) as exc:
        try:
            # lazy: heavy, and only there with the cluster extra (dask brings it)
            import cloudpickle
        except ImportError:
            raise pickle.PicklingError(str(exc)) from None
        try:
            return bytes(cloudpickle.dumps(obj))
        except Exception as exc2:
            raise pickle.PicklingError(str(exc2)) from None


def task_problems(jobs: int | None, scheduler: str | None, retries: int = RETRIES) -> list[str]:
    """Every reason :func:`run_tasks` cannot run with these options (empty when it can)."""
    problems = []
    if jobs is not None and (not isinstance(jobs, int) or jobs < 1):
        problems.append(f"jobs must be a whole number >= 1, found {jobs!r}")
    if not isinstance(retries, int) or retries < 0:
        problems.append(f"retries must be a whole number >= 0, found {retries!r}")
    if scheduler is not None and not (isinstance(scheduler, str) and scheduler.strip()):
        problems.append(f"scheduler must be 'local' or an address, found {scheduler!r}")
    elif scheduler is not None:
        problems += scheduler_problems(scheduler) + dask_problems()
    return problems


def scheduler_problems(scheduler: str) -> list[str]:
    """Why ``scheduler`` is neither ``local`` nor a dask scheduler address (empty when fine)."""
    if scheduler == "local":
        return []
    with_scheme = r"(tcp|tls|inproc|ucx|ws|wss)://[^\s/:]+(:\d{1,5})?/?"
    host_port = r"[^\s/:]+:\d{1,5}"
    if not (re.fullmatch(with_scheme, scheduler) or re.fullmatch(host_port, scheduler)):
        return [
            f"scheduler {scheduler!r} is neither 'local' nor an address such as tcp://host:8786"
        ]
    return []


def dask_problems() -> list[str]:
    """Why dask.distributed cannot be used here (empty when it can)."""
    try:
        # lazy: heavy, and an optional extra (tendonkit[cluster])
        import distributed  # noqa: F401
    except ImportError:
        return ["a dask scheduler needs dask.distributed: pip install 'tendonkit[cluster]'"]
    return []


def run_tasks(
    fn: Callable[[Any, Any], Any],
    payloads: Sequence[Any],
    *,
    shared: Any = None,
    jobs: int | None = 1,
    scheduler: str | None = None,
    retries: int = RETRIES,
    progress: bool = False,
    desc: str = "tasks",
    timeout: float | None = None,
) -> Iterator[Outcome]:
    """Run ``fn(shared, payload)`` for every payload; yield outcomes as tasks finish.

    Parameters
    ----------
    fn : callable
        A module-level function (workers import it by name).
    payloads : sequence
        One task each; must be picklable for the parallel engines.
    shared : object, optional
        Passed to every call; sent to each worker once.
    jobs : int or None
        Workers (None: this machine's cores); 1 without a scheduler runs here, in order.
    scheduler : str, optional
        ``"local"`` (a dask LocalCluster of ``jobs`` workers) or a dask scheduler address.
    retries : int
        How many times a task is started again after the worker holding it died.
    progress : bool
        A progress bar with the rate and the time left, on standard error.
    desc : str
        The progress bar's label.
    timeout : float, optional
        Seconds a task may run on the local process pool: a task still running then has its
        worker stopped and ends with a ``Timeout`` error (not retried).  This process cannot
        stop a task of its own, and dask does not stop a running task, so the serial and
        dask engines do not apply it.

    Yields
    ------
    Outcome
        In order of completion (in order of the payloads for the serial engine).

    Raises
    ------
    OptionError
        Bad ``jobs``, ``retries`` or ``scheduler``; dask not installed for a scheduler.
    SimulationError
        The dask scheduler cannot be reached.
    """
    raise_if(task_problems(jobs, scheduler, retries), OptionError, "Cannot run the tasks:")
    n_jobs = jobs if jobs is not None else default_jobs()
    # lazy: heavy (tqdm)
    from tqdm import tqdm

    if scheduler:
        it = _dask(fn, payloads, shared, n_jobs, scheduler, retries, desc)
    elif n_jobs > 1 and len(payloads) > 1:
        it = _processes(fn, payloads, shared, min(n_jobs, len(payloads)), retries, timeout)
    else:
        it = _serial(fn, payloads, shared)
    bar = tqdm(total=len(payloads), desc=desc, unit="task", disable=not progress, leave=False)
    retried = failed = 0
    try:
        for out in it:
            retried += out.attempts > 1
            failed += out.error is not None
            if retried or failed:
                bar.set_postfix(retried=retried, failed=failed, refresh=False)
            bar.update(1)
            yield out
    finally:
        bar.close()
        close = getattr(it, "close", None)
        if close is not None:
            close()


def map_tasks(
    fn: Callable[[Any, Any], Any],
    payloads: Sequence[Any],
    *,
    shared: Any = None,
    jobs: int | None = 1,
    scheduler: str | None = None,
    name: Callable[[int], str] | None = None,
    done: Callable[[int], None] | None = None,
) -> list[Any]:
    """The values of :func:`run_tasks` in the order of the payloads; the first error raises.

    For sweeps inside tendonkit (SINDYc thresholds, ARX structures, diagnose's effects): a
    failed task is a bug there, not an outcome to tabulate.  ``name(i)`` names task ``i`` in
    that error (default ``"Task i of n"``); ``done(i)`` is called as each task's value arrives
    (a progress bar).

    Raises
    ------
    SimulationError
        A task raised or its workers kept dying (the message names the task).
    """
    values: list[Any] = [None] * len(payloads)
    for out in run_tasks(fn, payloads, shared=shared, jobs=jobs, scheduler=scheduler):
        if out.error is not None:
            what = name(out.index) if name else f"Task {out.index} of {len(payloads)}"
            raise SimulationError(f"{what} failed: {out.error}")
        values[out.index] = out.value
        if done is not None:
            done(out.index)
    return values


# -- serial ------------------------------------------------------------------------------------


def _serial(
    fn: Callable[[Any, Any], Any], payloads: Sequence[Any], shared: Any
) -> Iterator[Outcome]:
    me = worker_id()
    for i, payload in enumerate(payloads):
        value, error, seconds = _call(fn, shared, payload)
        yield Outcome(i, value, error, 1, me, seconds)


# -- a local process pool that knows which task a dead worker held -----------------------------


def _worker_main(conn: Connection, fn: Callable[[Any, Any], Any], shared_blob: bytes) -> None:
    """A pool worker: one task at a time from ``conn`` until None or the pipe closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the master's to handle
    _one_thread()
    shared = pickle.loads(shared_blob)
    me = worker_id()
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        index, payload = msg
        try:  # the task's clock starts now, not when it was queued behind the start-up
            conn.send((STARTED, index))
        except OSError:
            return
        value, error, seconds = _call(fn, shared, payload)
        try:
            conn.send((index, value, error, me, seconds))
        except (pickle.PicklingError, TypeError, AttributeError) as exc:
            conn.send((index, None, f"the result cannot be sent back: {exc}", me, seconds))
        except OSError:
            return


#: A worker's message that it begins a task (its timeout counts from then).
STARTED = "started"
#: How long a worker may take to start (a fresh interpreter importing the task's function and
#: its shared data; tens of seconds on a loaded machine) before the time of its first task counts.
STARTUP_ALLOWANCE_S = 120.0


@dataclass
class _Slot:
    process: Any
    conn: Connection
    task: int | None = None
    #: When the task's timeout clock started (the worker's word that it began the task), or until
    #: then the time the task was sent plus :data:`STARTUP_ALLOWANCE_S`, the start-up's deadline.
    since: float = 0.0
    started: bool = False


def _processes(
    fn: Callable[[Any, Any], Any],
    payloads: Sequence[Any],
    shared: Any,
    n_workers: int,
    retries: int,
    timeout: float | None,
) -> Iterator[Outcome]:
    ctx = multiprocessing.get_context("spawn")
    blob = dumps(shared)
    queue: deque[int] = deque(range(len(payloads)))
    attempts = [0] * len(payloads)
    timed_out: set[int] = set()
    remaining = len(payloads)

    def start() -> _Slot:
        parent, child = ctx.Pipe()
        proc = ctx.Process(target=_worker_main, args=(child, fn, blob), daemon=True)
        proc.start()
        child.close()
        return _Slot(proc, parent)

    def give(slot: _Slot) -> None:
        if not queue:
            return
        i = queue.popleft()
        attempts[i] += 1
        slot.task, slot.since, slot.started = i, time.monotonic() + STARTUP_ALLOWANCE_S, False
        try:
            slot.conn.send((i, payloads[i]))
        except OSError:  # the worker died before it could take it: the task waits for another
            attempts[i] -= 1
            queue.appendleft(i)
            slot.task = None

    slots = [start() for _ in range(n_workers)]
    try:
        for s in slots:
            give(s)
        while remaining:
            wait_s = None
            if timeout is not None:
                # each busy worker's deadline: its task's timeout once it began it, else the end
                # of its start-up allowance
                busy = [
                    s.since + (timeout if s.started else 0.0) for s in slots if s.task is not None
                ]
                wait_s = max(0.0, min(busy) - time.monotonic()) if busy else timeout
            ready = set(wait([s.conn for s in slots] + [s.process.sentinel for s in slots], wait_s))
            for k, s in enumerate(slots):
                late = (
                    timeout is not None
                    and s.task is not None
                    and time.monotonic() - s.since > (timeout if s.started else 0.0)
                )
                if not (s.conn in ready or s.process.sentinel in ready or late):
                    continue
                got = None
                with contextlib.suppress(EOFError, OSError):
                    if s.conn.poll():
                        got = s.conn.recv()
                if got is not None and got[0] == STARTED:
                    if s.task == got[1]:
                        s.since, s.started = time.monotonic(), True
                    continue
                if got is not None:
                    index, value, error, who, seconds = got
                    s.task = None
                    remaining -= 1
                    yield Outcome(index, value, error, attempts[index], who, seconds)
                    give(s)
                    continue
                if late and s.process.is_alive():
                    assert s.task is not None
                    if s.started:
                        timed_out.add(s.task)
                    # else the worker did not start within the allowance: it is replaced and the
                    # task, which never ran, is started again like a dead worker's
                    s.process.kill()
                if s.process.is_alive():
                    continue
                # the worker died (or was stopped): replace it, start its task again or give up
                s.process.join()
                code = s.process.exitcode
                lost = s.task
                s.conn.close()
                slots[k] = fresh = start()
                if lost is not None:
                    if lost in timed_out:
                        remaining -= 1
                        yield Outcome(
                            lost,
                            None,
                            f"{TIMEOUT}: the task ran longer than {timeout:g} s; its worker "
                            "was stopped",
                            attempts[lost],
                            "",
                            float(timeout or 0.0),
                        )
                    elif attempts[lost] <= retries:
                        queue.appendleft(lost)
                    else:
                        remaining -= 1
                        yield Outcome(
                            lost,
                            None,
                            f"{WORKER_DIED}: the worker running it died {attempts[lost]} times "
                            f"(last exit code {code})",
                            attempts[lost],
                            "",
                            0.0,
                        )
                give(fresh)
    finally:
        for s in slots:
            try:
                s.conn.send(None)
            except OSError:
                pass
        for s in slots:
            s.process.join(timeout=2.0)
            if s.process.is_alive():
                s.process.kill()
                s.process.join()
            s.conn.close()


# -- dask.distributed ------------------------------------------------------------------------

#: Name of the worker plugin that holds the tasks' shared data on every dask worker.
_SHARED_PLUGIN = "tendonkit-shared"


def _dask_call(fn: Callable[[Any, Any], Any], plugin: str, payload: Any) -> tuple[Any, ...]:
    # lazy: heavy, and an optional extra (tendonkit[cluster])
    from distributed import get_worker

    _one_thread()
    shared = get_worker().plugins[plugin].shared  # type: ignore[attr-defined]
    value, error, seconds = _call(fn, shared, payload)
    return value, error, worker_id(), seconds


def _suspicious(dask_scheduler: Any, keys: list[Any]) -> dict[Any, int]:
    """Runs on the scheduler: how many workers died while holding each task."""
    tasks = dask_scheduler.tasks
    return {k: int(getattr(tasks[k], "suspicious", 0)) if k in tasks else 0 for k in keys}


def _connect(scheduler: str, n_workers: int, retries: int) -> tuple[Any, Any]:
    """(client, cluster or None) for ``scheduler``; SimulationError when it cannot be reached."""
    try:
        # lazy: heavy, and an optional extra (tendonkit[cluster])
        import dask
        from distributed import Client, LocalCluster
    except ImportError:
        raise OptionError(
            "A dask scheduler needs dask.distributed: pip install 'tendonkit[cluster]'."
        ) from None
    # one task per worker thread at a time (no queue on the workers), so a worker that dies
    # holds one task only
    config = {
        "distributed.scheduler.allowed-failures": retries,
        "distributed.scheduler.worker-saturation": 1.0,
    }
    if scheduler == "local":
        # our own workers: no statistical profiler sampling every task thread every 10 ms
        # (it costs the co-simulations about 5 % of a core each; benchmarks/README.md)
        config["distributed.worker.profile.enabled"] = False
    cluster = None
    with dask.config.set(config):
        try:
            if scheduler == "local":
                cluster = LocalCluster(
                    n_workers=n_workers,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=":0",  # any free port: never clash with a cluster of the user
                    silence_logs=50,  # logging.CRITICAL: a killed worker is reported by us
                )
                return Client(cluster), cluster
            return Client(scheduler, timeout="20s"), None
        except Exception as exc:  # a bad address, a refused connection, a timeout
            if cluster is not None:
                cluster.close()
            raise SimulationError(
                f"Cannot reach the dask scheduler {scheduler!r}: {type(exc).__name__}: {exc}"
            ) from None


def _dask(
    fn: Callable[[Any, Any], Any],
    payloads: Sequence[Any],
    shared: Any,
    n_workers: int,
    scheduler: str,
    retries: int,
    desc: str,
) -> Iterator[Outcome]:
    # lazy: heavy, and an optional extra (tendonkit[cluster])
    from distributed import WorkerPlugin, as_completed

    client, cluster = _connect(scheduler, n_workers, retries)

    class Shared(WorkerPlugin):  # type: ignore[misc]
        """The tasks' shared data, installed on every worker, also on those that join later
        (a worker restarted after a crash), unlike scattered data, which dies with its worker."""

        def __init__(self, data: Any, quick_exit: bool) -> None:
            self.shared = data
            self.quick_exit = quick_exit

        def teardown(self, worker: Any) -> None:
            # The plant FMU (a pythonfmu slave hosted by the worker's own interpreter) corrupts
            # the heap while a dask worker process finalises ("free(): corrupted unsorted
            # chunks" after the work is done; results are not affected).  Our own local
            # cluster's closing workers have nothing left to save and leave at once.
            if self.quick_exit:
                os._exit(0)

    token = hashlib.sha1(f"{desc}{time.time_ns()}{os.getpid()}".encode()).hexdigest()[:10]
    plugin = f"{_SHARED_PLUGIN}-{token}"
    try:
        try:
            client.register_plugin(Shared(shared, cluster is not None), name=plugin)
        except Exception as exc:
            raise SimulationError(
                f"Cannot send the tasks' data to the dask workers: {type(exc).__name__}: {exc}"
            ) from None
        todo = deque(range(len(payloads)))
        index: dict[Any, int] = {}
        pending = as_completed()

        def submit() -> None:
            # as many tasks in flight as the cluster has threads: with single-threaded workers
            # (a LocalCluster here; `dask worker --nthreads 1` elsewhere) a worker that dies
            # holds one task only
            slots = max(sum(client.nthreads().values()), 1)
            while todo and pending.count() < slots:
                i = todo.popleft()
                fut = client.submit(
                    _dask_call, fn, plugin, payloads[i], key=f"{desc}-{token}-{i}", pure=False
                )
                index[fut.key] = i
                pending.add(fut)

        submit()
        while not pending.is_empty():
            batch = pending.next_batch(block=True)
            try:
                died: dict[Any, int] = client.run_on_scheduler(
                    _suspicious, keys=[f.key for f in batch]
                )
            except Exception:  # a scheduler without tendonkit: attempts unknown, counted as 1
                died = {}
            for fut in batch:
                i = index.pop(fut.key)
                starts = died.get(fut.key, 0)
                if fut.status == "finished":
                    value, error, who, seconds = fut.result()
                    yield Outcome(i, value, error, 1 + starts, who, seconds)
                else:
                    why = fut.exception() if fut.status == "error" else None
                    name = type(why).__name__ if why is not None else fut.status
                    if name == "KilledWorker":
                        # the scheduler gave up after `retries` more starts, each on a worker
                        # that died
                        error, attempts = f"{WORKER_DIED}: {why}", max(starts, retries + 1)
                    else:
                        error, attempts = f"{name}: {why if why is not None else ''}", 1 + starts
                    yield Outcome(i, None, error.strip(), attempts, "", 0.0)
                fut.release()
            submit()
    finally:
        if cluster is None:  # a cluster of others: leave its workers as they were
            with contextlib.suppress(Exception):
                client.unregister_worker_plugin(plugin)
        client.close()
        if cluster is not None:
            cluster.close()
