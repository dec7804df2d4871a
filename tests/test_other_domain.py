"""The other domain (recon.synth.other, crowd, photos, look, clothes): what a sample holds, that it
is reproducible, the same under another CPU's kernels (up to a few pixels), and its pieces."""
import os
import subprocess
import sys

import numpy as np
import pytest

from recon import camera
from recon.errors import MissingFile
from recon.render import look
from recon.synth import dataset, photos
from recon.synth.dataset import SynthDataset, pack

pytestmark = pytest.mark.skipif(not photos.available(), reason="the photo packages are not extracted "
                                "(scripts/setup.sh)")
OTHER_CPU = {"ATEN_CPU_CAPABILITY": "default", "ONEDNN_MAX_CPU_ISA": "SSE41", "MKL_CBWR": "COMPATIBLE",
             "OPENCV_CPU_DISABLE": "AVX2,AVX,FP16,SSE4_2,SSE4_1", "OPENCV_IPP": "disabled",
             "NPY_DISABLE_CPU_FEATURES": "X86_V3", "LP_NUM_THREADS": "1"}


@pytest.fixture(scope="module")
def sampler(body):
    from recon.synth.other import OtherConfig, OtherSceneSampler

    return OtherSceneSampler(body, "test", 5, OtherConfig(random_outfits=1), pool=32)


def test_a_sample_holds_a_framed_dressed_person_and_its_truth(sampler):
    for i in range(4):
        s = sampler.sample(i)
        h, w = s["rgb"].shape[:2]
        assert (w, h) in ((640, 480), (480, 640))
        assert np.array_equal(s["rgb"], look.unjpeg(s["rgb_jpg"]))  # the image is its JPEG
        for key in ("mask", "silhouette", "parts", "depth"):
            assert s[key].shape == (h, w)
        np.testing.assert_allclose(s["points2d"], camera.project(s["points3d"].astype(np.float64), s["K"]),
                                   atol=0.05)
        assert s["K"][0, 2] == w / 2 and s["K"][1, 2] == h / 2
        assert 0.6 * max(w, h) - 1e-3 <= s["K"][0, 0] <= 1.6 * max(w, h) + 1e-3
        yaw, cut, outfit, quality, aspect = s["info"]
        assert -180 <= yaw <= 180 and 0 <= cut <= 1 and 40 <= quality <= 95 and aspect == pytest.approx(h / w)
        dressed = s["parts"] == 25
        assert dressed.any() == (outfit >= 0)
        assert (s["mask"] & ~(s["silhouette"] | dressed)).sum() <= 0.02 * s["mask"].sum() + 5
        assert 0.0 <= s["shape"].min() and s["shape"].max() <= 1.0


def test_a_sample_is_the_same_bytes_again(sampler, body):
    a, b = sampler.sample(3), sampler.sample(3)
    assert all(np.array_equal(a[k], b[k]) if not isinstance(a[k], bytes) else a[k] == b[k] for k in a)


RENDER = """
import sys
import numpy as np
from recon import kernels
kernels.pin()
import torch
torch.set_num_threads(1)
from recon.body import default_body
from recon.synth.dataset import bench_sampler
from recon.synth.other import OtherConfig, OtherSceneSampler
n, out, bench = int(sys.argv[1]), sys.argv[2], sys.argv[3]
s = (bench_sampler(bench, default_body()) if bench else
     OtherSceneSampler(default_body(), "test", 5, OtherConfig(random_outfits=1), pool=32))
np.savez(out, **{f"{i}/{k}": v for i in range(n) for k, v in s.sample(i).items() if k != "rgb_jpg"})
"""


def _render(n: int, env: dict, out, bench: str = "") -> dict:
    subprocess.run([sys.executable, "-c", RENDER, str(n), str(out), bench], capture_output=True, check=True,
                   env={**os.environ, **env})
    with np.load(out) as z:
        return {k: z[k] for k in z.files}


def _close_renders(a: dict, b: dict) -> None:
    """Two renders of the same samples agree: the truth to float32's last bits,
    the images up to a few pixels. A nearest-vertex query that meets a tie (a symmetric body) may pick
    another vertex when the last bit of a float64 differs, which moves a garment vertex by < 1 mm."""
    assert a.keys() == b.keys()
    for k in a:
        name = k.split("/")[1]
        if name in ("rgb", "mask", "silhouette", "parts", "depth"):
            x, y = a[k].astype(np.float64), b[k].astype(np.float64)
            far = np.abs(x - y).reshape(x.shape[0], x.shape[1], -1).max(-1) > (8 if name == "rgb" else 0.01)
            assert far.mean() < 0.003, (k, far.mean())
        else:
            np.testing.assert_allclose(a[k].astype(np.float64), b[k].astype(np.float64), rtol=0, atol=1e-5,
                                       err_msg=k)


def test_the_same_samples_under_another_cpus_kernels(tmp_path):
    """Garments through DeePSD and PBNS in float64, shading with exactly rounded operations, integer
    anti-aliasing, JPEG: the same samples whatever SIMD paths torch, oneDNN, MKL, OpenCV and NumPy take."""
    _close_renders(_render(2, {}, tmp_path / "a.npz"), _render(2, OTHER_CPU, tmp_path / "b.npz"))


def test_a_shard_of_jpeg_images_reads_back(sampler, tmp_path):
    samples = [sampler.sample(i) for i in range(2)]
    arrays = pack(samples, store_vertices=False)
    assert "rgb_jpg" in arrays and "rgb_png" not in arrays and "vertices" not in arrays
    np.savez(tmp_path / "shard-00000.npz", **arrays)
    (tmp_path / "manifest.json").write_text('{"shard_size": 2, "n": 2, "shards": {"0": ""}}')
    ds = SynthDataset(tmp_path)
    for i, s in enumerate(samples):
        got = ds[i]
        assert np.array_equal(got["rgb"], s["rgb"]) and np.array_equal(got["mask"], s["mask"])
        np.testing.assert_array_equal(got["info"], s["info"])
    light = SynthDataset(tmp_path, keys=("shape",))[1]
    assert set(light) == {"shape"}


def test_person_free_frames_and_crowds(body):
    from recon.synth.crowd import MAX_PEOPLE, CrowdConfig, CrowdSampler, EmptySampler

    e = EmptySampler(None, "test", 3).sample(0)
    assert set(e) == {"rgb", "rgb_jpg", "K", "info"}
    c = CrowdSampler(body, "test", 3, CrowdConfig(people=(2, 3)), pool=32, random_outfits=0).sample(0)
    n = int(c["n_people"])
    assert 2 <= n <= 3 and c["points2d"].shape == (MAX_PEOPLE, 42, 2)
    assert set(np.unique(c["ids"])) <= set(range(n + 1))
    assert np.all((c["visible"][:n] >= 0) & (c["visible"][:n] <= 1)) and not c["visible"][n:].any()
    assert np.all(c["heights"][:n] > 20)


def test_a_photo_that_is_not_the_benchmarks_is_refused(tmp_path, monkeypatch):
    name = photos.other_photo_names()[0]
    package, folder, _ = next(p for p in photos.OTHER_PHOTOS if any(n == name for n, _ in p[2]))
    fake = tmp_path / "photos" / package / folder / name
    fake.parent.mkdir(parents=True)
    fake.write_bytes(b"not that photo")
    monkeypatch.setattr(photos, "photos_dir", lambda: tmp_path / "photos")
    photos.load_photo.cache_clear()
    try:
        with pytest.raises(MissingFile):
            photos.load_photo(name)
    finally:
        photos.load_photo.cache_clear()


def test_the_reserved_photo_packages_are_in_no_data_set():
    used = {p for p, _, _ in photos.OTHER_PHOTOS}
    assert not used & set(photos.RESERVED_PACKAGES)
    assert {"other-val", "other-test", "other-empty-test", "other-crowd-test"} <= set(dataset.BENCHMARKS)


def test_integer_power_and_anti_aliasing_are_exact():
    x = np.array([0.0, 0.3, 0.9, 1.0])
    np.testing.assert_array_equal(look.int_power(x, 5), x * x * x * x * x)
    img2 = np.arange(16, dtype=np.uint8).reshape(4, 4)[..., None].repeat(3, 2)
    small = look.downsample2(img2)
    assert small.shape == (2, 2, 3) and small[0, 0, 0] == (0 + 1 + 4 + 5 + 2) // 4
    bg = np.full((2, 2, 3), 100, np.uint8)
    covered = np.zeros((4, 4), bool)
    covered[:2, :2] = True
    out = look.composite2(np.full((4, 4, 3), 200, np.uint8), covered, bg)
    assert out[0, 0, 0] == 200 and out[1, 1, 0] == 100
    covered[0, 2] = True  # one of four sub-samples
    assert look.composite2(np.full((4, 4, 3), 200, np.uint8), covered, bg)[0, 1, 0] == 125


@pytest.mark.slow
def test_other_test_rendered_with_another_cpus_kernels_is_the_same_benchmark(tmp_path):
    """other-test's first 25 samples under every kernel choice of OTHER_CPU: the same truth and the
    same images up to a few pixels (the committed hashes check a regeneration on the same kernels)."""
    _close_renders(_render(25, {}, tmp_path / "a.npz", "other-test"),
                   _render(25, OTHER_CPU, tmp_path / "b.npz", "other-test"))
