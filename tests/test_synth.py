"""Rasteriser conventions, IoU, the scene sampler and sharded dataset storage."""
import json

import numpy as np
import pytest

from recon import report
from recon.bench import runner
from recon.bench.methods import mediapipe_to_joints
from recon.errors import ReconError
from recon.synth import dataset
from recon.synth.dataset import SynthDataset, generate
from recon.synth.raster import Rasterizer, projection, silhouette_iou
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
    monkeypatch.setattr(runner, "bench_dir", lambda name: d)
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
