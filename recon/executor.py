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

Ray: ``address`` (or ``$RAY_ADDRESS``) joins a running cluster; without one a local Ray is started
with this machine's cores and stopped after the job. The kernel and log variables of this process
(``recon.kernels.PINNED``, MediaPipe's quiet flags) travel to every worker, so all of them run the
same float kernels as a local run.
"""
from __future__ import annotations

import logging
import multiprocessing as mp
import os
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any

import torch

from recon.errors import ReconError
from recon.kernels import PINNED

try:
    import ray
    from ray.exceptions import ActorDiedError, ActorUnavailableError, RayActorError, RayTaskError, WorkerCrashedError
except ImportError:  # the optional extra recon[cluster]
    ray = None

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
    while the driver handles results). start_timeout: seconds to wait for a first Ray worker."""

    kind: str = "local"
    workers: int | None = None
    address: str | None = None
    retries: int = 2
    in_flight: int = 2
    start_timeout: float = 300.0

    def __post_init__(self):
        if self.kind not in EXECUTORS:
            raise ReconError(f"executor must be one of {EXECUTORS}, got {self.kind!r}")
        if self.workers is not None and self.workers < 1:
            raise ReconError("workers must be at least 1")
        if self.kind == "local" and self.address:
            raise ReconError("--ray-address needs --executor ray")
        if self.kind == "ray" and ray is None:
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
        worker = spec.build()
        for i, task in enumerate(tasks):
            yield i, worker(prepare(task))
    elif config.kind == "local":
        yield from _local(spec, tasks, config, prepare)
    else:
        yield from _ray(spec, tasks, config, prepare)


class _Retries:
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
    todo, ctx = _Retries(len(tasks), cfg.retries), mp.get_context("spawn")
    while todo:
        pool = ProcessPoolExecutor(cfg.workers, mp_context=ctx, initializer=_init_local,
                                   initargs=(spec, torch.get_num_threads()))
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


class RayWorker:
    """The actor around a worker: built by the first task (so that its errors come back as that
    task's), ``run`` per task; ``pid`` answers once the process is up."""

    def __init__(self, spec: WorkerSpec, threads: int):
        torch.set_num_threads(threads)
        self.spec, self.worker = spec, None

    def pid(self) -> int:
        return os.getpid()

    def run(self, task):
        if self.worker is None:
            self.worker = self.spec.build()
        return self.worker(task)


def ray_available() -> bool:
    return ray is not None


def start_actor(spec: WorkerSpec, threads: int = 1):
    """One ``RayWorker`` actor (one CPU, not restarted by Ray: callers replace lost ones)."""
    return ray.remote(num_cpus=1, max_restarts=0, max_task_retries=0)(RayWorker).remote(spec, threads)


ACTOR_LOST = (ActorDiedError, ActorUnavailableError, RayActorError, WorkerCrashedError) if ray is not None else ()


def connect(address: str | None = None) -> bool:
    """Join ``address`` (default ``$RAY_ADDRESS``) or start a local Ray with this machine's cores,
    unless Ray is already running in this process; True when this call started it."""
    if ray is None:
        raise ReconError(NO_RAY)
    if ray.is_initialized():
        return False
    env = {var: os.environ[var] for var in FORWARDED_ENV if var in os.environ}
    kw = {"include_dashboard": False, "log_to_driver": log_.isEnabledFor(logging.DEBUG),
          "logging_level": logging.WARNING, "runtime_env": {"env_vars": env}}
    address = address or os.environ.get("RAY_ADDRESS")
    try:
        if address:
            ray.init(address=address, **kw)
        else:
            ray.init(num_cpus=os.cpu_count(), **kw)
    except ConnectionError as e:
        raise ReconError(f"cannot join the Ray cluster at {address}: {e}") from e
    return True


def cluster_cpus() -> int:
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def _ray(spec: WorkerSpec, tasks: Sequence, cfg: ExecutorConfig, prepare) -> Iterator[tuple[int, Any]]:
    """One actor per worker (one CPU each), ``in_flight`` tasks queued at each. A dead actor is
    replaced (on any node with a free CPU) and its tasks go to the live ones."""
    started = connect(cfg.address)
    n = cfg.workers or cluster_cpus()
    threads = torch.get_num_threads()
    todo = _Retries(len(tasks), cfg.retries)
    starting: dict = {}  # ready-call -> actor not yet known to be alive
    load: dict = {}  # live actor -> tasks in flight
    running: dict = {}  # task call -> (task index, actor)
    replacements = n * (cfg.retries + 1)

    def start():
        actor = start_actor(spec, threads)
        starting[actor.pid.remote()] = actor

    def bury(actor):
        load.pop(actor, None)
        ray.kill(actor, no_restart=True)

    for _ in range(n):
        start()
    waited_from = time.monotonic()
    try:
        while todo or running:
            for actor in sorted(load, key=load.get):
                if todo.suspects:  # each alone on an idle actor; the others drain meanwhile
                    if load[actor] == 0:
                        i = todo.suspects.popleft()
                        running[actor.run.remote(prepare(tasks[i]))] = (i, actor)
                        load[actor] += 1
                    continue
                while todo.queue and load[actor] < cfg.in_flight:
                    i = todo.queue.popleft()
                    running[actor.run.remote(prepare(tasks[i]))] = (i, actor)
                    load[actor] += 1
            if not load and not starting:
                raise ReconError("every Ray worker died and none could be replaced (no free CPU left in the "
                                 "cluster?)")
            if not load and time.monotonic() - waited_from > cfg.start_timeout:
                raise ReconError(f"no Ray worker started within {cfg.start_timeout:.0f} s (no free CPU in the "
                                 "cluster, or the workers cannot build: run with -v for their logs)")
            ready, _ = ray.wait([*running, *starting], num_returns=1, timeout=10.0)
            for ref in ready:
                if ref in starting:
                    actor = starting.pop(ref)
                    try:
                        ray.get(ref)
                        load[actor] = 0
                    except ACTOR_LOST:
                        if replacements > 0:
                            replacements -= 1
                            start()
                    continue
                i, actor = running.pop(ref)
                load[actor] -= 1
                try:
                    result = ray.get(ref)
                except RayTaskError as e:
                    raise e.as_instanceof_cause() from None
                except ACTOR_LOST:  # every task in flight on that actor is lost with it
                    refs = [r for r, (_, a) in running.items() if a is actor]
                    lost = [i] + [running.pop(r)[0] for r in refs]
                    log_.warning("a Ray worker died; its %d task(s) in flight run again", len(lost))
                    bury(actor)
                    waited_from = time.monotonic()
                    if replacements > 0:
                        replacements -= 1
                        start()
                    for j in todo.lost_together(lost):
                        yield j, WorkerLost(f"its Ray worker died {todo.lost[j]} times")
                    continue
                yield i, result
    finally:
        for actor in [*load, *starting.values(), *(a for _, a in running.values())]:
            ray.kill(actor, no_restart=True)
        if started:
            ray.shutdown()

