"""The commands on Ray (``--executor ray``) against the local executor: the same files bit for bit,
a worker killed mid-run loses nothing, a stopped run resumes. Slow tier; needs recon[cluster]."""
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from recon import executor as ex
from recon.backbone.crops import OnlineCrops, RayCrops
from recon.bench.runner import run_method
from recon.demo import example_photos
from recon.run import RunOptions, run
from recon.synth.dataset import generate
from recon.synth.scene import SceneSampler, SynthConfig
from recon.synth.video import Actor, ClipRenderer, ClipSpec, write_clip
from recon.video import SmoothConfig, VideoOptions
from recon.video.many import videos

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not ex.ray_available(), reason="Ray is the optional extra recon[cluster]")]
RAY2 = ex.ExecutorConfig("ray", workers=2)
cluster = pytest.importorskip("recon.executor.cluster")  # the slow tier's Ray tests need recon[cluster]
RECON = [sys.executable, "-m", "recon.cli"]


@pytest.fixture(scope="module", autouse=True)
def local_ray():
    cluster.connect()  # one local Ray for the module (map_tasks leaves a Ray it did not start running)
    yield
    cluster.ray.shutdown()


def files(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (the run's timings, which differ run to run, and the results page,
    named by its files' times, left out)."""
    out = {}
    for p in sorted(folder.rglob("*")):
        if not p.is_file() or p.name in ("summary.json", "videos.json", "index.html") or ".recon-page" in p.parts:
            continue
        data = p.read_bytes()
        if p.name in ("result.json", "video.json"):
            js = json.loads(data)
            for key in ("timings_ms", "seconds", "frames_per_second"):
                js.pop(key, None)
            data = json.dumps(js, sort_keys=True).encode()
        out[p.relative_to(folder).as_posix()] = data
    return out


def test_recon_run_on_ray_writes_the_same_files_as_in_this_process(tmp_path):
    options = RunOptions(batch_size=2)
    here = run(example_photos(), tmp_path / "here", options, progress=False, log=lambda m: None)
    on_ray = run(example_photos(), tmp_path / "ray", options, progress=False, log=lambda m: None, executor=RAY2)
    assert here.done == on_ray.done == ["astronaut", "cameraman", "grace_hopper"]
    a, b = files(tmp_path / "here"), files(tmp_path / "ray")
    assert sorted(a) == sorted(b) and len(a) >= 3 * 6
    assert [k for k in a if a[k] != b[k]] == []


def _photos(folder: Path, n: int) -> Path:
    folder.mkdir()
    for i in range(n):
        src = example_photos()[i % 3]
        shutil.copy(src, folder / f"p{i}{Path(src).suffix}")
    return folder


def _ray_worker_pids() -> list[int]:
    pids = []
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and b"ray::RayWorker" in (proc / "cmdline").read_bytes():
                pids.append(int(proc.name))
        except OSError:
            continue
    return pids


def _wait_for(cond, timeout: float = 300.0):
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.1)


def _summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def test_a_killed_ray_worker_loses_nothing_and_a_stopped_run_resumes(tmp_path):
    n = 16  # enough that a run is still busy well after its first image
    photos = _photos(tmp_path / "photos", n)
    keys = sorted(f"p{i}" for i in range(n))
    env = {**os.environ, "RECON_THREADS": "1"}
    out = tmp_path / "out"
    cmd = [*RECON, "run", str(photos), "--out", str(out), "--executor", "ray", "--workers", "2", "--batch-size", "1",
           "--no-overlay"]
    cluster.ray.shutdown()  # the command starts its own local Ray
    p = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for(lambda: any((out / k / "result.json").exists() for k in keys))
    victims = _ray_worker_pids()
    assert victims, "no Ray worker process found"
    os.kill(victims[0], signal.SIGKILL)
    _, err = p.communicate(timeout=600)
    assert p.returncode == 0, err
    assert "a Ray worker died" in err
    s = _summary(out)
    assert s["done"] == keys and s["failed"] == {} and not s["interrupted"]
    # nothing twice, no staging left
    assert sorted(x.name for x in out.iterdir()) == sorted([*keys, ".recon-page", "index.html", "summary.json"])
    for k in keys:
        assert {"result.json", "body.obj", "body.glb", "pose.bvh"} <= {f.name for f in (out / k).iterdir()}
        assert json.loads((out / k / "result.json").read_text())["made_from"]["input_sha256"]

    # the driver killed (kill -9) just after its first image, then the same command again
    out2 = tmp_path / "out2"
    cmd2 = [*cmd[:cmd.index("--out") + 1], str(out2), *cmd[cmd.index("--out") + 2:]]
    p = subprocess.Popen(cmd2, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _wait_for(lambda: any((out2 / k / "result.json").exists() for k in keys))
    p.kill()
    p.wait(timeout=60)
    subprocess.run([str(Path(sys.executable).with_name("ray")), "stop", "--force"], capture_output=True, timeout=120)
    before = sorted(k for k in keys if (out2 / k / "result.json").exists())
    assert 1 <= len(before) < n
    r = subprocess.run(cmd2, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    again = _summary(out2)
    assert sorted(again["unchanged"]) == before and sorted(again["done"] + again["unchanged"]) == keys
    assert files(out2) == files(out)  # the same files as the uninterrupted run
    cluster.connect()


def test_synth_generate_on_ray_is_bit_identical(tmp_path):
    a = generate(tmp_path / "a", "test", 3, 6, shard_size=2, workers=1, progress=False)
    b = generate(tmp_path / "b", "test", 3, 6, shard_size=2, progress=False, executor=RAY2)
    ma, mb = (json.loads((d / "manifest.json").read_text()) for d in (a, b))
    assert ma == mb and len(ma["shards"]) == 3


def test_eval_on_ray_gives_the_same_scores(body):
    scenes = SceneSampler(body, "test", 5, SynthConfig())
    samples = [scenes.sample(i) for i in range(10)]
    for method in ("mean", "smplr-gt2d"):
        here = run_method(method, samples, body, progress=False)
        on_ray = run_method(method, samples, body, progress=False, executor=RAY2)
        for r in (here, on_ray):
            r.pop("seconds_per_image")
        assert here == on_ray


def test_videos_on_ray_write_the_same_files_and_report_a_bad_one(body, tmp_path):
    spec = ClipSpec("test-walk", (Actor("12_01", 20),), 12, seed=5, distance=4.0)
    frames, _ = ClipRenderer(body).render(spec)
    clip = write_clip(frames, tmp_path / "walk.mp4")
    shutil.copy(clip, tmp_path / "again.mp4")
    (tmp_path / "broken.mp4").write_bytes(b"not a video")
    inputs = [tmp_path / "walk.mp4", tmp_path / "again.mp4", tmp_path / "broken.mp4"]
    options = VideoOptions(overlay=False, smooth=SmoothConfig(steps=20))
    here = videos(inputs, tmp_path / "here", options, progress=False, log=lambda m: None)
    on_ray = videos(inputs, tmp_path / "ray", options, executor=RAY2, progress=False, log=lambda m: None)
    for s in (here, on_ray):
        assert list(s.done) == ["walk", "again"] and list(s.failed) == [str(tmp_path / "broken.mp4")]
    a, b = files(tmp_path / "here"), files(tmp_path / "ray")
    assert any(k.endswith("motion.bvh") for k in a)
    assert sorted(a) == sorted(b) and [k for k in a if a[k] != b[k]] == []
    assert a["walk/track_0/motion.bvh"] == a["again/track_0/motion.bvh"]  # each video its own fresh source


def test_ray_rendering_actors_stream_the_loader_workers_crops():
    stream = RayCrops(64, 4, actors=1, seed=3)
    it = iter(stream)
    batch = next(it)
    it.close()
    crops = iter(OnlineCrops(64, seed=3, stream=0))
    expected = torch.utils.data.default_collate([next(crops) for _ in range(4)])
    assert batch[0].shape == (4, 3, 64, 64)
    for got, want in zip(batch, expected, strict=True):
        np.testing.assert_array_equal(got.numpy(), want.numpy())
