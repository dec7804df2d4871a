"""recon.executor: the same results from every executor, lost workers replaced and their tasks run
again, worker errors surfaced; Ray's tests (a local Ray, a two-node cluster on this machine) are
in the slow tier."""
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from recon import executor as ex
from recon.cli import main
from recon.errors import ReconError

needs_ray = pytest.mark.skipif(not ex.ray_available(), reason="Ray is the optional extra recon[cluster]")


class Doubler:
    """A test worker: ``task * 2`` and its process id; kills its own process on ``die_on`` (once,
    or every time with ``always``), raises ReconError on ``fail_on`` (-1: when built)."""

    def __init__(self, marker: str, die_on: int | None = None, always: bool = False, fail_on: int | None = None,
                 pause: float = 0.05):
        if fail_on == -1:
            raise ReconError("no weights for this worker")
        self.marker, self.die_on, self.always, self.fail_on, self.pause = Path(marker), die_on, always, fail_on, pause

    def __call__(self, task: int):
        if task == self.die_on and (self.always or not self.marker.exists()):
            self.marker.write_text("died")
            os.kill(os.getpid(), signal.SIGKILL)
        if task == self.fail_on:
            raise ReconError(f"task {task} is bad input")
        time.sleep(self.pause)
        return task * 2, os.getpid()


if ex.ray_available():  # the workers unpickle this test module's classes by value
    from recon.executor import cluster
    cluster.ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])


def _run(tmp_path, config, n=12, **kw):
    spec = ex.WorkerSpec(Doubler, (str(tmp_path / "marker"),), kw)
    return dict(ex.map_tasks(spec, list(range(n)), config))


def test_config_is_checked():
    with pytest.raises(ReconError, match="executor must be"):
        ex.ExecutorConfig("dask")
    with pytest.raises(ReconError, match="at least 1"):
        ex.ExecutorConfig(workers=0)
    with pytest.raises(ReconError, match="needs --executor ray"):
        ex.ExecutorConfig("local", address="127.0.0.1:6379")
    assert ex.ExecutorConfig().in_process and not ex.ExecutorConfig(workers=2).in_process
    assert not ex.ExecutorConfig(workers=2).remote
    if ex.ray_available():
        assert ex.ExecutorConfig("ray").remote


def test_in_process_runs_every_task_in_order(tmp_path):
    spec = ex.WorkerSpec(Doubler, (str(tmp_path / "m"),), {"pause": 0})
    out = list(ex.map_tasks(spec, [3, 1, 2], prepare=lambda t: t + 1))
    assert [(i, r[0]) for i, r in out] == [(0, 8), (1, 4), (2, 6)]
    assert {r[1] for _, r in out} == {os.getpid()}


class Threads:
    """A test worker: the torch threads it runs with."""

    def __call__(self, task):
        return torch.get_num_threads()


def test_a_job_sets_its_workers_threads_and_gives_this_process_its_own_back():
    before = torch.get_num_threads()
    wanted = 2 if before == 1 else 1
    assert ex.in_order(ex.WorkerSpec(Threads), [0, 1], ex.ExecutorConfig(threads=wanted)) == [wanted, wanted]
    assert torch.get_num_threads() == before
    assert ex.in_order(ex.WorkerSpec(Threads), [0, 1, 2], ex.ExecutorConfig(workers=2, threads=wanted)) == [wanted] * 3
    with pytest.raises(ReconError, match="threads"):
        ex.ExecutorConfig(threads=0)


def test_a_stateless_function_runs_as_a_worker_and_results_keep_the_tasks_order():
    assert ex.in_order(ex.WorkerSpec(ex.Call, (abs,)), [-3, 2, -1], ex.ExecutorConfig(workers=2)) == [3, 2, 1]


@pytest.mark.slow
def test_a_strict_job_stops_on_a_task_that_kills_every_worker(tmp_path):
    spec = ex.WorkerSpec(Doubler, (str(tmp_path / "marker"),), {"die_on": 2, "always": True})
    with pytest.raises(ex.WorkerLost):
        dict(ex.map_strict(spec, list(range(4)), ex.ExecutorConfig(workers=2, retries=0)))


def test_local_workers_replace_a_killed_worker_and_lose_nothing(tmp_path):
    got = _run(tmp_path, ex.ExecutorConfig(workers=2), die_on=5)
    assert (tmp_path / "marker").exists()  # a worker did die
    assert sorted(got) == list(range(12)) and all(got[i][0] == 2 * i for i in got)
    assert os.getpid() not in {r[1] for r in got.values()}


@pytest.mark.slow
def test_a_task_that_kills_every_worker_is_given_up_the_others_finish(tmp_path):
    got = _run(tmp_path, ex.ExecutorConfig(workers=2, retries=1), n=6, die_on=2, always=True)
    assert isinstance(got[2], ex.WorkerLost)
    assert all(got[i][0] == 2 * i for i in got if i != 2)


def test_a_worker_error_stops_the_job_as_in_this_process(tmp_path):
    with pytest.raises(ReconError, match="task 3 is bad input"):
        _run(tmp_path, ex.ExecutorConfig(), fail_on=3)
    with pytest.raises(ReconError, match="task 3 is bad input"):
        _run(tmp_path, ex.ExecutorConfig(workers=2), fail_on=3)
    with pytest.raises(ReconError, match="no weights"):  # a worker that cannot be built
        _run(tmp_path, ex.ExecutorConfig(workers=2), fail_on=-1)


def test_without_ray_the_error_says_how_to_install_it(monkeypatch):
    monkeypatch.setattr(ex, "ray_available", lambda: False)
    with pytest.raises(ReconError, match=r"recon\[cluster\]"):
        ex.ExecutorConfig("ray")


def test_command_line_flags(capsys):
    from recon.cli import build_parser

    args = build_parser(["run"]).parse_args(["run", "x.jpg", "--out", "o", "--executor", "ray", "--workers", "3",
                                             "--ray-address", "10.0.0.1:6379"])
    assert (args.executor, args.workers, args.ray_address) == ("ray", 3, "10.0.0.1:6379")
    assert main(["run", "x.jpg", "--out", "o", "--ray-address", "10.0.0.1:6379"]) == 2
    assert "needs --executor ray" in capsys.readouterr().err


@pytest.fixture
def local_ray():
    """A local Ray for the test (map_tasks then leaves it running)."""
    cluster.connect()
    yield cluster.ray


@pytest.mark.slow
@needs_ray
def test_ray_runs_every_task_in_actors_and_replaces_a_killed_one(tmp_path, local_ray, monkeypatch):
    started = []  # which results come from which actor is timing: count the actors started instead
    start_actor = cluster.start_actor
    monkeypatch.setattr(cluster, "start_actor", lambda *a, **kw: started.append(1) or start_actor(*a, **kw))
    got = _run(tmp_path, ex.ExecutorConfig("ray", workers=2), n=16, die_on=5)
    assert (tmp_path / "marker").exists()
    assert sorted(got) == list(range(16)) and all(got[i][0] == 2 * i for i in got)
    assert os.getpid() not in {r[1] for r in got.values()}
    assert len(started) == 3  # two workers and the one replacing the killed worker


@pytest.mark.slow
@needs_ray
def test_ray_gives_up_a_poison_task_and_surfaces_worker_errors(tmp_path, local_ray):
    got = _run(tmp_path, ex.ExecutorConfig("ray", workers=2, retries=1), n=6, die_on=2, always=True)
    assert isinstance(got[2], ex.WorkerLost) and all(got[i][0] == 2 * i for i in got if i != 2)
    with pytest.raises(ReconError, match="task 3 is bad input"):
        _run(tmp_path, ex.ExecutorConfig("ray", workers=2), fail_on=3)
    with pytest.raises(ReconError, match="no weights"):
        _run(tmp_path, ex.ExecutorConfig("ray", workers=2), fail_on=-1)


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _raylets() -> set[int]:
    pids = set()
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and (proc / "cmdline").read_bytes().split(b"\0")[0].endswith(b"/raylet"):
                pids.add(int(proc.name))
        except OSError:
            continue
    return pids


def _parent(pid: int) -> int | None:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, ValueError, IndexError):
        return None


@pytest.mark.slow
@needs_ray
def test_a_lost_node_of_a_two_node_cluster_loses_no_task(tmp_path, caplog):
    """`ray start --head` and a second raylet on the loopback address, one CPU each (with the
    session's token, tests/conftest.py); the second node's raylet and worker are killed while its
    actor has tasks in flight."""
    ray_cli = str(Path(sys.executable).with_name("ray"))
    port = _free_port()
    common = ["--num-cpus", "1", "--node-ip-address", "127.0.0.1", "--disable-usage-stats"]
    if cluster.ray.is_initialized():
        cluster.ray.shutdown()
    try:
        subprocess.run([ray_cli, "start", "--head", "--port", str(port), "--include-dashboard", "false", *common],
                       check=True, capture_output=True, timeout=120)
        before = _raylets()
        subprocess.run([ray_cli, "start", "--address", f"127.0.0.1:{port}", *common], check=True,
                       capture_output=True, timeout=120)
        [raylet] = _raylets() - before  # the second node's
        cluster.connect(f"127.0.0.1:{port}")
        nodes = cluster.ray.nodes()
        assert len(nodes) == 2
        second = next(n for n in nodes if "node:__internal_head__" not in n["Resources"])
        spec = ex.WorkerSpec(Doubler, (str(tmp_path / "m"),), {"pause": 0.2})
        got, killed = {}, []
        for i, r in ex.map_tasks(spec, list(range(48)), ex.ExecutorConfig("ray", workers=2)):
            got[i] = r
            if not killed and _parent(r[1]) == raylet:
                # the second node's actor answered (however late it started: its share of the tasks
                # waits for it), with tasks still in flight: a lost machine takes its raylet and its
                # workers at once (a worker alone outlives its raylet a while; actor calls go to it)
                killed = [raylet, r[1]]
                for pid in killed:
                    os.kill(pid, signal.SIGKILL)
        assert killed, "the second node's actor never answered"
        assert sorted(got) == list(range(48)) and all(got[i][0] == 2 * i for i in got)
        assert "a Ray worker died" in caplog.text  # its tasks in flight were lost and ran again
        deadline = time.monotonic() + 120
        while [n["Alive"] for n in cluster.ray.nodes() if n["NodeID"] == second["NodeID"]] != [False]:
            assert time.monotonic() < deadline, "the killed node is still alive for Ray"
            time.sleep(1)
    finally:
        cluster.ray.shutdown()
        subprocess.run([ray_cli, "stop", "--force"], capture_output=True, timeout=120)


def test_ray_is_imported_only_for_a_ray_job():
    """Ray takes about a second to import: the commands and the executor load it only when a job runs on it."""
    code = ("import sys\nimport recon.run, recon.video.many, recon.synth.dataset, recon.bench.runner, "
            "recon.backbone.train\nassert 'ray' not in sys.modules, 'ray imported'")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]


CTRL_C_DRIVER = '''
import signal, sys, time
from pathlib import Path
from recon import executor as ex

# Ctrl-C as in a terminal: a background job of a non-interactive shell (a CI runner's) starts with
# SIGINT ignored, and Python then leaves it ignored
signal.signal(signal.SIGINT, signal.default_int_handler)

class Sleeper:
    def __init__(self, marker):
        self.marker = Path(marker)

    def __call__(self, task):
        self.marker.write_text("running")
        time.sleep(120)

try:
    for _ in ex.map_tasks(ex.WorkerSpec(Sleeper, (sys.argv[1],)), [0, 1], ex.ExecutorConfig("ray", workers=1)):
        pass
except KeyboardInterrupt:  # map_tasks has killed its actors and stopped the Ray it started
    Path(sys.argv[2]).write_text(repr(time.time()))
    sys.exit(130)
'''


@pytest.mark.slow
@needs_ray
def test_ctrl_c_stops_a_ray_driver_within_two_seconds(tmp_path):
    """A driver waiting on its actors (a local Ray it started) is back in the caller's hands, its
    actors killed and its Ray stopped, within 2 s of SIGINT."""
    script, running, stopped = tmp_path / "driver.py", tmp_path / "running", tmp_path / "stopped"
    script.write_text(CTRL_C_DRIVER)
    if ex.ray_available() and cluster.ray.is_initialized():
        cluster.ray.shutdown()
    p = subprocess.Popen([sys.executable, str(script), str(running), str(stopped)])
    try:
        deadline = time.monotonic() + 180
        while not running.exists():
            assert p.poll() is None and time.monotonic() < deadline, "the Ray worker never started"
            time.sleep(0.1)
        time.sleep(1.0)  # the driver is blocked on its actors
        sent = time.time()
        p.send_signal(signal.SIGINT)
        assert p.wait(30) == 130
        assert float(stopped.read_text()) - sent < 2.0
    finally:
        if p.poll() is None:
            p.kill()
