"""The executors side by side in one run: `recon run` and synthetic generation with 1 and 2
workers, local processes against Ray actors; the backbone's online crops delivered to the trainer
with 1 and 2 rendering actors; Ray's cost per task and the driver's per image; the scaling they
project.

    .venv/bin/python benchmarks/bench_ray.py [--images 4 16] [--samples 16 64] [--seconds 20]

Throughput is the marginal rate between a small and a large job of each configuration (start-up:
a local Ray, workers loading their models, is reported apart), the configurations interleaved.
Ray's overhead per image is its marginal time per image over the local executor's at the same
worker count. -> eval/results/bench-ray.{json,md} (``--render``: the Markdown again from the JSON)
"""
from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

from recon import kernels

kernels.pin()
os.environ.setdefault("GLOG_minloglevel", "2")
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import torch  # noqa: E402
from torch.utils.data import DataLoader  # noqa: E402

from recon import report  # noqa: E402
from recon.backbone.crops import OnlineCrops, RayCrops  # noqa: E402
from recon.backbone.hourglass import SIZES  # noqa: E402
from recon.demo import example_photos  # noqa: E402
from recon.executor import ExecutorConfig, WorkerSpec, map_tasks  # noqa: E402
from recon.executor.cluster import connect, ray  # noqa: E402
from recon.run import Outcome, RunOptions, RunSummary, run  # noqa: E402
from recon.run.batch import record  # noqa: E402
from recon.synth.dataset import generate  # noqa: E402

OUT = Path(__file__).resolve().parent.parent / "eval" / "results" / "bench-ray"
CONFIGS = (("local", 1), ("local", 2), ("ray", 1), ("ray", 2))


class Echo:
    """A worker that does nothing: what is left is the executor's own cost per task."""

    def __call__(self, task):
        return task


def photos(folder: Path, n: int) -> Path:
    folder.mkdir(parents=True)
    for i in range(n):
        src = example_photos()[i % 3]
        shutil.copy(src, folder / f"p{i:03d}{Path(src).suffix}")
    return folder


def run_job(kind: str, workers: int, n: int, root: Path) -> float:
    with tempfile.TemporaryDirectory(dir=root) as d:
        inputs = photos(Path(d) / "in", n)
        t = time.perf_counter()
        s = run([inputs], Path(d) / "out", RunOptions(), progress=False, log=lambda m: None,
                executor=ExecutorConfig(kind, workers=workers))
        assert len(s.done) == n, s.line()
        return time.perf_counter() - t


def synth_job(kind: str, workers: int, n: int, root: Path) -> float:
    with tempfile.TemporaryDirectory(dir=root) as d:
        t = time.perf_counter()
        generate(Path(d) / "s", "test", 0, n, shard_size=8, progress=False,
                 executor=ExecutorConfig(kind, workers=workers))
        return time.perf_counter() - t


def marginal(job, sizes: tuple[int, int], root: Path, rounds: int) -> list[list]:
    """Per configuration: [executor, workers, items/s (marginal), start-up s, s per item], from
    the best of ``rounds`` interleaved runs of each job size."""
    times = {c: {} for c in CONFIGS}
    for _ in range(rounds):
        for n in sizes:  # interleaved: each size over every configuration
            for c in CONFIGS:
                times[c][n] = min(times[c].get(n, float("inf")), job(*c, n, root))
    a, b = sizes
    rows = []
    for c in CONFIGS:
        per = (times[c][b] - times[c][a]) / (b - a)
        rows.append([c[0], c[1], 1 / per, times[c][a] - a * per, per])
    for r in rows:  # Ray's time per item over the local executor's at the same worker count
        local = next(x for x in rows if x[0] == "local" and x[1] == r[1])
        r.append(r[4] / local[4] - 1 if r[0] == "ray" else None)
    return rows


def crops_per_second(make, seconds: float) -> float:
    it = iter(make())
    next(it)  # start-up
    t, n = time.perf_counter(), 0
    while time.perf_counter() - t < seconds:
        n += len(next(it)[0])
    rate = n / (time.perf_counter() - t)
    if hasattr(it, "close"):
        it.close()
    return rate


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--images", type=int, nargs=2, default=(4, 16))
    ap.add_argument("--samples", type=int, nargs=2, default=(64, 320))
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--render", action="store_true", help="only rewrite bench-ray.md from bench-ray.json")
    args = ap.parse_args()
    if args.render:
        data = report.read(OUT)
        print(Path(report.write(OUT, data, render(data))).read_text())
        return
    torch.set_num_threads(1)
    root = Path(tempfile.mkdtemp(prefix="bench-ray-"))
    try:
        images = marginal(run_job, tuple(args.images), root, args.rounds)
        samples = marginal(synth_job, tuple(args.samples), root, args.rounds)
        # the executors' own cost per task, and the driver's per image (its folder written in place)
        connect()
        echo = {}
        for n in (100, 1100):  # marginal: the actors' start-up left out
            t = time.perf_counter()
            list(map_tasks(WorkerSpec(Echo), list(range(n)), ExecutorConfig("ray", workers=2)))
            echo[n] = time.perf_counter() - t
        ray_task_ms = 1000 * (echo[1100] - echo[100]) / 1000
        with tempfile.TemporaryDirectory(dir=root) as d:
            out = Path(d) / "out"
            run([example_photos()[0]], out, RunOptions(), progress=False, log=lambda m: None)
            folder = out / Path(example_photos()[0]).stem
            files = {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}
            outcome = Outcome("x.jpg", "x", "done", files=files)
            staging = out / ".staging"
            staging.mkdir()
            t = time.perf_counter()
            for i in range(20):
                record(RunSummary(), out, staging, Outcome("x.jpg", f"x{i}", "done", files=outcome.files), print)
            record_ms = 1000 * (time.perf_counter() - t) / 20
            image_mb = sum(map(len, files.values())) / 1e6
        size = SIZES["base"].input_size
        crops = []
        for n in (1, 2):
            crops.append(["Ray actors", n, crops_per_second(lambda n=n: RayCrops(size, 16, n), args.seconds)])
        ray.shutdown()
        for n in (1, 2):
            crops.append(["DataLoader workers", n, crops_per_second(
                lambda n=n: DataLoader(OnlineCrops(size), batch_size=16, num_workers=n,
                                       multiprocessing_context="spawn", persistent_workers=True), args.seconds)])
    finally:
        shutil.rmtree(root, ignore_errors=True)
    per_image = next(r[4] for r in images if r[0] == "local" and r[1] == 1)
    overhead = next(r[5] for r in images if r[0] == "ray" and r[1] == 1)
    driver_s = (record_ms + ray_task_ms) / 1000
    projection = [[w, min(w / (per_image * (1 + max(overhead, 0))), 1 / driver_s)] for w in (1, 2, 8, 32, 128, 512)]
    data = {"machine": report.machine(), "images": args.images, "samples": args.samples, "rounds": args.rounds,
            "seconds": args.seconds, "crop_size": size, "recon_run": images, "synth": samples,
            "ray_task_ms": ray_task_ms, "driver_record_ms": record_ms, "image_folder_mb": image_mb, "crops": crops,
            "projection": projection}
    print(Path(report.write(OUT, data, render(data))).read_text())


def render(d: dict) -> str:
    """bench-ray.md from its JSON."""
    heads = ["start-up s", "s each", "Ray overhead"]
    fmts = ["", "", ".2f", ".1f", ".2f", "+.1%"]
    (a, b), (sa, sb) = d["images"], d["samples"]
    return "\n".join([
        "# Executors: local processes against Ray actors", "",
        f"`benchmarks/bench_ray.py`; {report.describe(d['machine'])}. Marginal rates between a small and a large "
        f"job of each configuration (best of {d['rounds']} interleaved rounds); start-up is the rest (a local Ray, "
        "workers loading their models). Ray overhead: Ray's time per item over the local executor's at the same "
        "worker count.", "",
        f"`recon run` (default options, the bundled photos copied to {a} and {b} images):", "",
        report.table(d["recon_run"], ["executor", "workers", "images/s (marginal)", *heads], fmts), "",
        f"`recon synth generate` ({sa} and {sb} samples, shards of 8). Under Ray the driver writes and hashes each "
        "shard while the actors render the next ones; locally each worker (or this process, with one) does that "
        "itself, so Ray's rate is the higher here:", "",
        report.table(d["synth"], ["executor", "workers", "samples/s (marginal)", *heads], fmts), "",
        f"Costs outside the workers: a Ray task that does nothing {d['ray_task_ms']:.2f} ms (2 actors, marginal over "
        f"1,000 tasks); the driver writing one image's folder ({d['image_folder_mb']:.1f} MB, moved into place) "
        f"{d['driver_record_ms']:.1f} ms.", "",
        "Projected `recon run` throughput on a cluster: workers / (the local s per image x (1 + Ray's overhead)), "
        "each worker a core as fast as this one, up to the driver's bound 1 / (its write + a task):", "",
        report.table(d["projection"], ["workers", "images/s"], ["", ".1f"]), "",
        f"Backbone online crops ({d['crop_size']} px, batches of 16) delivered to the trainer, {d['seconds']:.0f} s "
        "each:", "",
        report.table(d["crops"], ["renderers", "count", "crops/s"], ["", "", ".1f"])])


if __name__ == "__main__":
    main()
