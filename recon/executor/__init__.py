"""Where the tasks of a batch job run: in this process, in local worker processes, or on a Ray
cluster (``pip install 'recon[cluster]'``).

A job is a sequence of tasks and a ``WorkerSpec`` (a class and its arguments): every worker
process, or Ray actor, builds its worker once (models loaded once) and calls it on each task it
is given. ``map_tasks`` yields ``(index, result)`` as tasks finish, in any order; callers keep
results by index, so what they write does not depend on the executor or the number of workers.

A worker process that dies (killed, out of memory, its node lost) loses only its tasks in flight:
they go to another worker, each at most ``retries`` more times, after which its result is a
``WorkerLost`` (the caller reports the task's inputs as failed). An exception raised by a worker
itself (a ``ReconError``, a bug) stops the job, as it does in this process.

Ray (``recon.executor.cluster``, imported only for a Ray job): ``address`` (or ``$RAY_ADDRESS``)
joins a running cluster; without one a local Ray is started with this machine's cores and stopped
after the job. The kernel and log variables of this process
(``recon.kernels.PINNED``, MediaPipe's quiet flags) travel to every worker, so all of them run the
same float kernels as a local run.
"""
from __future__ import annotations

import importlib
import importlib.util
import logging
import multiprocessing as mp
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any

import torch
from tqdm import tqdm

from recon.errors import ReconError
from recon.kernels import PINNED

EXECUTORS = ("local", "ray")
FORWARDED_ENV = (*(var for var, _ in PINNED), "GLOG_minloglevel", "TF_CPP_MIN_LOG_LEVEL", "PYOPENGL_PLATFORM",
                 "OMP_NUM_THREADS")
NO_RAY = "--executor ray needs Ray: pip install 'recon[cluster]' (scripts/setup.sh installs it)"
log_ = logging.getLogger(__name__)


@dataclass(frozen=True)
class ExecutorConfig:
    """kind: "local" or "ray". workers: worker processes or actors (local default 1: this process;
    Ray default: every CPU of the cluster). address: the Ray cluster to join (default
    ``$RAY_ADDRESS``; none: a local Ray with this machine's cores). retries: how many more times a
    task lost with its worker is tried. in_flight: tasks queued at each worker (keeps it busy
    while the driver handles results). start_timeout: seconds to wait for a first Ray worker.
    threads: torch threads of each worker (default: this process's; in this process too, for
    the job's time)."""

    kind: str = "local"
    workers: int | None = None
    address: str | None = None
    retries: int = 2
    in_flight: int = 2
    start_timeout: float = 300.0
    threads: int | None = None

    def __post_init__(self):
        if self.kind not in EXECUTORS:
            raise ReconError(f"executor must be one of {EXECUTORS}, got {self.kind!r}")
        if self.workers is not None and self.workers < 1:
            raise ReconError("workers must be at least 1")
        if self.threads is not None and self.threads < 1:
            raise ReconError("threads must be at least 1")
        if self.kind == "local" and self.address:
            raise ReconError("--ray-address needs --executor ray")
        if self.kind == "ray" and not ray_available():
            raise ReconError(NO_RAY)

    @property
    def in_process(self) -> bool:
        """Whether tasks run in this process (``local`` with one worker)."""
        return self.kind == "local" and (self.workers or 1) == 1

    @property
    def remote(self) -> bool:
        """Whether workers may run on other machines (inputs then travel with the tasks)."""
        return self.kind == "ray"


@dataclass(frozen=True)
class WorkerSpec:
    """``cls(*args, **kwargs)`` builds a worker; ``worker(task)`` runs one task. Picklable: a
    top-level class and plain arguments."""

    cls: type
    args: tuple = ()
    kwargs: dict = field(default_factory=dict)

    def build(self):
        return self.cls(*self.args, **self.kwargs)


class WorkerLost(Exception):
    """The result of a task whose worker died on every try."""


def map_tasks(spec: WorkerSpec, tasks: Sequence, config: ExecutorConfig | None = None,
              prepare: Callable[[Any], Any] | None = None) -> Iterator[tuple[int, Any]]:
    """``(index, worker(prepare(tasks[index])))`` for every task, as they finish. ``prepare``
    (default: none) is called in this process just before a task is handed out, so that what it
    loads (image bytes, samples) is held only for the tasks in flight."""
    config = config or ExecutorConfig()
    prepare = prepare or (lambda t: t)
    if config.in_process:
        before = torch.get_num_threads()
        torch.set_num_threads(config.threads or before)
        try:
            worker = spec.build()
            for i, task in enumerate(tasks):
                yield i, worker(prepare(task))
        finally:
            torch.set_num_threads(before)
    elif config.kind == "local":
        yield from _local(spec, tasks, config, prepare)
    else:  # Ray loads only here (a second in every process otherwise)
        yield from importlib.import_module("recon.executor.cluster").map_actors(spec, tasks, config, prepare)


def map_strict(spec: WorkerSpec, tasks: Sequence, config: ExecutorConfig | None = None,
               prepare: Callable[[Any], Any] | None = None) -> Iterator[tuple[int, Any]]:
    """``map_tasks`` for a job that cannot leave a task out (training data, a results table): a
    task whose worker died on every try stops it (its ``WorkerLost`` is raised)."""
    for i, r in map_tasks(spec, tasks, config, prepare):
        if isinstance(r, WorkerLost):
            raise r
        yield i, r


def in_order(spec: WorkerSpec, tasks: Sequence, config: ExecutorConfig | None = None) -> list:
    """Every task's result, in the tasks' order (``map_strict``)."""
    out = [None] * len(tasks)
    for i, r in map_strict(spec, tasks, config):
        out[i] = r
    return out


class Call:
    """A worker with no state of its own: ``Call(fn)(task) = fn(task)`` (``fn`` a top-level function)."""

    def __init__(self, fn: Callable[[Any], Any]):
        self.fn = fn

    def __call__(self, task):
        return self.fn(task)


def stream_results(spec_of: Callable[[int], WorkerSpec], actors: int, address: str | None = None,
                   in_flight: int = 2) -> Iterator[Any]:
    """Endless results of Ray actors called without a task (e.g. batches of rendered training
    data): actor w's worker is ``spec_of(w)``, ``in_flight`` calls queued at each (the stream runs
    ahead of its reader by at most that much); a lost actor is replaced by one on a new stream."""
    return importlib.import_module("recon.executor.cluster").stream_actors(spec_of, actors, address, in_flight)


def ray_available() -> bool:
    """Whether the optional extra recon[cluster] (Ray) is installed, without importing it."""
    return importlib.util.find_spec("ray") is not None


def run_job(spec: WorkerSpec, tasks: Sequence, on_result: Callable[[int, Any], int],
            lost: Callable[[int, WorkerLost], Any], config: ExecutorConfig | None = None,
            prepare: Callable[[Any], Any] | None = None, desc: str = "", unit: str = "task",
            total: int | None = None, progress: bool = True) -> bool:
    """``map_tasks`` as the commands run it: each result handed to ``on_result(index, result)``
    (which returns how many of the ``total`` steps of the progress bar it completed), a task
    whose worker died on every try as ``lost(index, WorkerLost)``. Returns False when Ctrl-C
    stopped the job (its workers stopped; the caller still writes its summary)."""
    bar = tqdm(total=len(tasks) if total is None else total, desc=desc, unit=unit, disable=not progress)
    results = map_tasks(spec, tasks, config, prepare)
    try:
        for i, r in results:
            bar.update(on_result(i, lost(i, r) if isinstance(r, WorkerLost) else r))
        return True
    except KeyboardInterrupt:
        return False
    finally:
        results.close()
        bar.close()


class Retries:
    """The tasks still to run. Tasks lost together with a worker are suspects: each runs again
    alone, so that only a task that kills its worker by itself counts a loss (and is given up
    after ``retries`` more), not the tasks that happened to share the worker with it."""

    def __init__(self, n: int, retries: int):
        self.queue, self.suspects, self.lost, self.retries = deque(range(n)), deque(), [0] * n, retries

    def __bool__(self) -> bool:
        return bool(self.queue or self.suspects)

    def lost_together(self, tasks: list[int]) -> list[int]:
        """``tasks`` died with their worker: queued again as suspects; returns those given up."""
        given_up = []
        if len(tasks) == 1:  # it ran alone: it is what killed the worker
            i = tasks[0]
            self.lost[i] += 1
            if self.lost[i] > self.retries:
                given_up.append(i)
        self.suspects.extend(i for i in sorted(tasks) if i not in given_up)
        return given_up


_LOCAL: dict = {}


def _init_local(spec: WorkerSpec, threads: int) -> None:
    torch.set_num_threads(threads)
    _LOCAL["spec"] = spec


def _call_local(task):
    if "worker" not in _LOCAL:  # built by the first task: its errors (missing weights) reach the driver
        _LOCAL["worker"] = _LOCAL["spec"].build()
    return _LOCAL["worker"](task)


def _local(spec: WorkerSpec, tasks: Sequence, cfg: ExecutorConfig, prepare) -> Iterator[tuple[int, Any]]:
    """Spawned worker processes (fresh GL contexts, no inherited torch state); a pool broken by a
    dead worker is replaced and its tasks in flight queued again."""
    todo, ctx = Retries(len(tasks), cfg.retries), mp.get_context("spawn")
    while todo:
        pool = ProcessPoolExecutor(cfg.workers, mp_context=ctx, initializer=_init_local,
                                   initargs=(spec, cfg.threads or torch.get_num_threads()))
        running: dict = {}
        try:
            while todo or running:
                if todo.suspects:  # one at a time, alone in the pool
                    if not running:
                        i = todo.suspects.popleft()
                        running[pool.submit(_call_local, prepare(tasks[i]))] = i
                else:
                    while todo.queue and len(running) < cfg.workers * cfg.in_flight:
                        i = todo.queue.popleft()
                        running[pool.submit(_call_local, prepare(tasks[i]))] = i
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                broken = []
                for f in done:
                    i = running.pop(f)
                    try:
                        result = f.result()
                    except BrokenProcessPool:
                        broken.append(i)
                        continue
                    yield i, result
                if broken:
                    broken += running.values()  # the whole pool is gone: every task in flight
                    log_.warning("a worker process died; %d task(s) in flight run again", len(broken))
                    for i in todo.lost_together(broken):
                        yield i, WorkerLost(f"its worker process died {todo.lost[i]} times")
                    break
        finally:
            _stop_pool(pool)


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Shut down without waiting for tasks in flight (Ctrl-C, a broken pool)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in processes:
        if p.is_alive():
            p.terminate()
    for p in processes:
        p.join(5)
