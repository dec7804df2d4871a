"""Rasteriser conventions, IoU, the scene sampler and sharded dataset storage, the same on every CPU."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from recon import report
from recon.bench import runner
from recon.bench.methods import mediapipe_to_joints
from recon.errors import ReconError
from recon.render.raster import Rasterizer, projection, silhouette_iou
from recon.synth import dataset
from recon.synth.dataset import SynthDataset, generate
from recon.synth.scene import SceneSampler


@pytest.fixture(scope="module")
def raster():
    return Rasterizer(64, 48)


def test_projection_matches_pinhole():
    k = np.array([[50.0, 0, 30], [0, 60.0, 20], [0, 0, 1]])
    p = projection(k, 64, 48)
    x = np.array([0.3, -0.2, 2.0])  # OpenCV camera point
    clip = p @ np.array([x[0], -x[1], -x[2], 1.0])
    ndc = clip[:3] / clip[3]
    u, v = (ndc[0] + 1) * 64 / 2, (1 - ndc[1]) * 48 / 2  # row 0 at the top
    uv = (k @ x)[:2] / x[2]
    np.testing.assert_allclose([u, v], uv, atol=1e-4)


def test_render_square_lands_where_k_projects(raster):
    k = np.array([[40.0, 0, 32], [0, 40.0, 24], [0, 0, 1]])
    z = 2.0
    # a square of side 0.5 m centred at (0.5, 0.25, 2): pixels u in [37, 47], v in [24, 34]
    v = np.array([[0.25, 0.0, z], [0.75, 0.0, z], [0.75, 0.5, z], [0.25, 0.5, z]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    rgb, labels, depth = raster.render(v, f, k, labels=np.full(4, 7))
    ys, xs = np.nonzero(depth > 0)
    assert 36 <= xs.min() <= 38 and 46 <= xs.max() <= 48
    assert 23 <= ys.min() <= 25 and 33 <= ys.max() <= 35
    np.testing.assert_allclose(depth[depth > 0], z, atol=1e-4)
    assert set(np.unique(labels[depth > 0])) == {7} and (labels[depth == 0] == -1).all()


def test_silhouette_iou_hand_cases():
    a = np.zeros((4, 4), bool)
    a[:2] = True
    b = np.zeros((4, 4), bool)
    b[1:3] = True
    assert silhouette_iou(a, a) == 1.0
    assert silhouette_iou(a, ~a) == 0.0
    assert silhouette_iou(a, b) == pytest.approx(4 / 12)
    with pytest.raises(ValueError):
        silhouette_iou(a, np.zeros((3, 3), bool))


@pytest.fixture(scope="module")
def scene(body, mocap):
    return SceneSampler(body, "test", seed=11)


def test_scene_sample_is_consistent(scene):
    s = scene.sample(0)
    assert s["rgb"].shape == (256, 256, 3) and s["rgb"].dtype == np.uint8
    assert (s["mask"] <= s["silhouette"]).all() and s["silhouette"].any()
    assert ((s["parts"] > 0) == s["silhouette"]).all()
    uv = s["points3d"] @ s["K"].T
    np.testing.assert_allclose(uv[:, :2] / uv[:, 2:], s["points2d"], atol=1e-3)
    # the projected pelvis lies on the rendered body, at the rendered depth (+- body depth)
    u, v = s["points2d"][0].round().astype(int)
    if 0 <= u < 256 and 0 <= v < 256 and s["silhouette"][v, u]:
        assert abs(float(s["depth"][v, u]) - s["points3d"][0, 2]) < 0.3
    again = scene.sample(0)
    assert all(np.array_equal(again[k], s[k]) for k in s)
    assert not np.array_equal(scene.sample(1)["rgb"], s["rgb"])


def test_dataset_is_resumable_and_reproducible(tmp_path, body, mocap):
    a = generate(tmp_path / "a", "test", 3, 5, shard_size=2, workers=1, progress=False)
    man = json.loads((a / "manifest.json").read_text())
    assert sorted(man["shards"]) == ["0", "1", "2"]
    (a / "shard-00001.npz").unlink()  # interrupted run: a shard is missing
    generate(a, "test", 3, 5, shard_size=2, workers=1, progress=False)
    assert json.loads((a / "manifest.json").read_text())["shards"] == man["shards"]
    ds = SynthDataset(a)
    assert len(ds) == 5 and ds.verify() == []
    s = ds[4]
    assert s["rgb"].shape == (256, 256, 3) and s["vertices"].shape == (body.num_vertices, 3)
    assert s["depth"].dtype == np.float32 and s["mask"].dtype == bool
    few = SynthDataset(a, keys=("rgb", "K"), cache=1)  # what training crops read, shard after shard
    for i in (4, 0, 4):
        got = few[i]
        assert set(got) == {"rgb", "K"} and np.array_equal(got["rgb"], ds[i]["rgb"])
    with pytest.raises(ReconError, match="other settings"):
        generate(a, "train", 3, 5, shard_size=2, workers=1, progress=False)
    with pytest.raises(IndexError):
        ds[5]


def test_benchmark_runner_on_a_tiny_set(tmp_path, body, mocap, monkeypatch):
    d = dataset.generate(tmp_path / "tiny", "test", 9, 4, shard_size=4, workers=1, progress=False)
    monkeypatch.setitem(dataset.BENCHMARKS, "tiny", {"split": "test", "seed": 9, "n": 4})
    monkeypatch.setattr(runner, "open_bench", lambda name: dataset.SynthDataset(d))
    monkeypatch.setattr(runner, "CHECK_IMAGES", 2)
    md = runner.evaluate("tiny", ["mean"], out_dir=tmp_path / "res")
    data = report.read(md)
    res = data["rows"][0]
    assert res["images"] == 4 and res["failures"] == 0
    assert 0 < res["MPJPE-P2 (PA)"] <= res["MPJPE-P1"] < 2000 and 0 <= res["IoU"] <= 1
    assert res["PVE"] > 0 and set(res["groups"]) == set(runner.ABBR.values())
    # the check slice re-renders the first images of the benchmark's stream: the stored images
    assert data["check"]["kwargs"] == {"bench": "tiny", "methods": ["mean"], "n": 2}
    first2 = runner.run_method("mean", [SynthDataset(d)[i] for i in range(2)], body, progress=False)
    assert data["check"]["values"]["mean"]["MPJPE-P1"] == pytest.approx(first2["MPJPE-P1"], rel=1e-9)
    assert "| mean " in md.read_text()
    with pytest.raises(ReconError, match="unknown method"):
        runner.evaluate("tiny", ["nope"], out_dir=tmp_path / "res")


def test_mediapipe_mapping_shape():
    w = np.random.default_rng(0).normal(size=(33, 3))
    j = mediapipe_to_joints(w)
    assert j.shape == (24, 3)
    np.testing.assert_allclose(j[1], w[23])  # left hip = MediaPipe's left hip
    np.testing.assert_allclose(j[0], 0.5 * (w[23] + w[24]))


# what another CPU changes: torch's, oneDNN's, MKL's, OpenCV's and NumPy's SIMD paths and llvmpipe's
# thread count; Mesa's code path itself is pinned by recon.kernels whatever the CPU
OTHER_CPU = {"ATEN_CPU_CAPABILITY": "default", "ONEDNN_MAX_CPU_ISA": "SSE41", "MKL_CBWR": "COMPATIBLE",
             "OPENCV_CPU_DISABLE": "AVX2,AVX,FP16,SSE4_2,SSE4_1", "OPENCV_IPP": "disabled",
             "NPY_DISABLE_CPU_FEATURES": "X86_V3", "LP_NUM_THREADS": "1"}
RENDER = """
import hashlib, sys
from recon import kernels
kernels.pin()
import torch
torch.set_num_threads(1)
from recon.body import default_body
from recon.synth.dataset import BENCHMARKS, bench_config
from recon.synth.scene import SceneSampler
b = BENCHMARKS["synth-test"]
s = SceneSampler(default_body(), b["split"], b["seed"], bench_config("synth-test"))
for i in range(int(sys.argv[1])):
    h = hashlib.sha256()
    for k, v in sorted(s.sample(i).items()):
        h.update(k.encode() + v.tobytes())
    print(h.hexdigest())
"""


def _render_hashes(n: int, env: dict) -> list[str]:
    out = subprocess.run([sys.executable, "-c", RENDER, str(n)], capture_output=True, text=True, check=True,
                         env={**os.environ, **env})
    return out.stdout.split()


def test_the_same_samples_under_another_cpus_kernels():
    """Sample i of a benchmark is the same bytes (images, geometry, cameras) whatever SIMD paths the
    libraries take: the geometry is computed in float64, the renderer pinned (recon.kernels)."""
    assert _render_hashes(3, {}) == _render_hashes(3, OTHER_CPU)


@pytest.mark.slow
def test_a_benchmark_shard_rendered_with_another_cpus_kernels_is_the_committed_one(tmp_path):
    """synth-test's first shard, rendered with every kernel choice of OTHER_CPU, hashes to the
    committed reference (rendered with the pinned ones)."""
    code = ("from recon import kernels; kernels.pin()\n"
            "import sys; from pathlib import Path\n"
            "from recon.synth.dataset import BENCHMARKS, bench_config, generate\n"
            "b = BENCHMARKS['synth-test']\n"
            "generate(Path(sys.argv[1]), b['split'], b['seed'], 250, workers=1, cfg=bench_config('synth-test'),"
            " progress=False)\n")
    subprocess.run([sys.executable, "-c", code, str(tmp_path)], check=True, env={**os.environ, **OTHER_CPU},
                   capture_output=True)
    made = json.loads((tmp_path / "manifest.json").read_text())["shards"]["0"]
    assert made == json.loads(dataset.reference_hashes_path("synth-test").read_text())["shards"]["0"]
