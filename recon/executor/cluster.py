"""``recon.executor`` on a Ray cluster (the optional extra ``recon[cluster]``): one actor per
worker, imported by ``map_tasks`` only when a job runs on Ray."""
from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import ray
import torch
from ray.exceptions import ActorDiedError, ActorUnavailableError, RayActorError, RayTaskError, WorkerCrashedError

from recon.errors import ReconError
from recon.executor import FORWARDED_ENV, ExecutorConfig, Retries, WorkerLost, WorkerSpec

# the driver's longest wait on Ray in one call: a Ctrl-C (KeyboardInterrupt) is seen between calls
WAIT_S = 0.25
log_ = logging.getLogger("recon.executor")


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


def start_actor(spec: WorkerSpec, threads: int = 1):
    """One ``RayWorker`` actor (one CPU, not restarted by Ray: callers replace lost ones)."""
    return ray.remote(num_cpus=1, max_restarts=0, max_task_retries=0)(RayWorker).remote(spec, threads)


ACTOR_LOST = (ActorDiedError, ActorUnavailableError, RayActorError, WorkerCrashedError)


def connect(address: str | None = None) -> bool:
    """Join ``address`` (default ``$RAY_ADDRESS``) or start a local Ray with this machine's cores,
    unless Ray is already running in this process; True when this call started it."""
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


def map_actors(spec: WorkerSpec, tasks: Sequence, cfg: ExecutorConfig, prepare) -> Iterator[tuple[int, Any]]:
    """One actor per worker (one CPU each), ``in_flight`` tasks queued at each. A dead actor is
    replaced (on any node with a free CPU) and its tasks go to the live ones."""
    started = connect(cfg.address)
    n = cfg.workers or cluster_cpus()
    threads = cfg.threads or torch.get_num_threads()
    todo = Retries(len(tasks), cfg.retries)
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
            ready, _ = ray.wait([*running, *starting], num_returns=1, timeout=WAIT_S)
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



def stream_actors(spec_of: Callable[[int], WorkerSpec], actors: int, address: str | None,
                  in_flight: int) -> Iterator[Any]:
    """``recon.executor.stream_results`` on Ray."""
    started = connect(address)
    streams = {start_actor(spec_of(w)): w for w in range(actors)}
    running = {a.run.remote(None): a for a in streams for _ in range(in_flight)}
    try:
        while True:
            ready, _ = ray.wait(list(running), num_returns=1, timeout=WAIT_S)
            if not ready:
                continue
            actor = running.pop(ready[0])
            try:
                result = ray.get(ready[0])
            except ACTOR_LOST:
                if actor in streams:  # its other queued calls fail too: replaced once
                    w = streams.pop(actor) + actors
                    actor = start_actor(spec_of(w))
                    streams[actor] = w
                    running.update({actor.run.remote(None): actor for _ in range(in_flight)})
                continue
            running[actor.run.remote(None)] = actor
            yield result
    finally:
        for actor in streams:
            ray.kill(actor, no_restart=True)
        if started:
            ray.shutdown()
