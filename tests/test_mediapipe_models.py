"""MediaPipe's three landmark models: chosen by name, a missing file falls back to full (one warning,
no download attempt), an unknown name is refused before anything runs."""
import json
import logging
import subprocess
import sys

import numpy as np
import pytest
import skimage.data
import torch

from recon import paths
from recon.cli import build_parser
from recon.errors import MissingFile, ReconError
from recon.keypoints import train
from recon.keypoints.adapter import KeypointAdapter, weights_for
from recon.keypoints.sources import MediaPipeSource
from recon.people import guard, mediapipe
from recon.pipeline import Reconstructor
from recon.reconstruction import ReconstructorConfig

needs_mediapipe = pytest.mark.skipif(not mediapipe.available(), reason="needs mediapipe (scripts/setup.sh)")


@needs_mediapipe
def test_model_files_live_in_mediapipes_package():
    for name in mediapipe.MODELS:
        path = mediapipe.model_file(name)
        assert path.name == f"pose_landmark_{name}.tflite"
        assert path.parent.name == "pose_landmark"
    assert mediapipe.model_file("full").is_file()  # the wheel's own


def test_an_unknown_model_is_refused():
    with pytest.raises(ReconError, match="heavy"):
        mediapipe.model_file("huge")
    with pytest.raises(ReconError, match="keypoint_model"):
        Reconstructor(keypoint_model="huge")


@needs_mediapipe
def test_a_missing_model_falls_back_to_full_with_one_warning(monkeypatch, tmp_path, caplog):
    real = mediapipe.model_file
    monkeypatch.setattr(mediapipe, "model_file", lambda m: tmp_path / "absent.tflite" if m == "heavy" else real(m))
    monkeypatch.setattr(mediapipe, "_WARNED", set())
    with caplog.at_level(logging.WARNING, logger="recon"):
        assert mediapipe.resolve_model("heavy") == "full"
        assert mediapipe.resolve_model("heavy") == "full"
        assert mediapipe.resolve_model("full") == "full"
    assert len([r for r in caplog.records if "heavy" in r.getMessage()]) == 1


@needs_mediapipe
@pytest.mark.skipif(not (mediapipe.available() and mediapipe.model_file("heavy").is_file()),
                    reason="the heavy model is installed by scripts/setup.sh (npm)")
def test_heavy_and_full_find_the_same_person():
    rgb = skimage.data.astronaut()
    full, heavy = mediapipe.MediaPipePose("full"), mediapipe.MediaPipePose("heavy")
    a, b = full(rgb), heavy(rgb)
    assert heavy.model == "heavy" and a is not None and b is not None
    # two models, one person: the landmarks agree to a fraction of her size but are not the same numbers
    size = np.ptp(a.image_xy, axis=0).max()
    d = np.linalg.norm(a.image_xy - b.image_xy, axis=1)
    assert np.median(d) < 0.1 * size
    assert d.max() > 0


def test_the_flag_chooses_the_model_and_refuses_others(capsys):
    parser = build_parser()
    assert parser.parse_args(["run", "--out", "o", "--keypoint-model", "heavy"]).keypoint_model == "heavy"
    assert parser.parse_args(["run", "--out", "o"]).keypoint_model == mediapipe.DEFAULT_MODEL == "heavy"
    with pytest.raises(SystemExit) as e:
        parser.parse_args(["run", "--out", "o", "--keypoint-model", "huge"])
    assert e.value.code == 2 and "--keypoint-model" in capsys.readouterr().err


@needs_mediapipe
def test_a_result_records_the_model_that_ran(monkeypatch, tmp_path):
    """Asked for heavy without its file, a result says full: installing heavy later redoes it."""
    real = mediapipe.model_file
    monkeypatch.setattr(mediapipe, "model_file", lambda m: tmp_path / "absent.tflite" if m == "heavy" else real(m))
    assert ReconstructorConfig(keypoint_model="heavy").as_installed().keypoint_model == "full"
    assert ReconstructorConfig(keypoint_model="lite", source="backbone").as_installed().keypoint_model == "lite"
    monkeypatch.undo()
    if mediapipe.model_file("heavy").is_file():
        assert ReconstructorConfig(keypoint_model="heavy").as_installed().keypoint_model == "heavy"


@needs_mediapipe
def test_collecting_with_a_missing_model_is_refused(monkeypatch, tmp_path):
    """An adapter's training data from another model than the one asked for would be silently wrong."""
    monkeypatch.setattr(train, "model_file", lambda m: tmp_path / "absent.tflite")
    with pytest.raises(MissingFile, match="heavy"):
        train.collect(tmp_path / "no-data", tmp_path / "out", model="heavy")
    assert not (tmp_path / "out").exists()


def test_each_landmark_model_reads_the_adapter_trained_on_its_answers():
    """heavy's landmarks differ from full's (above): each has its adapter, whose training record names
    the model it was collected with; lite, without one, reads full's."""
    assert weights_for("lite") == weights_for("full") != weights_for("heavy")
    for model in ("full", "heavy"):
        meta = json.loads(paths.load_checkpoint(weights_for(model), "recon keypoints train")["meta_json"])
        assert meta.get("keypoint_model", "full") == model
    a, b = KeypointAdapter.load(model="full"), KeypointAdapter.load(model="heavy")
    assert any(not torch.equal(x, y) for x, y in zip(a.state_dict().values(), b.state_dict().values(), strict=True))


@needs_mediapipe
def test_the_source_uses_the_adapter_and_guard_of_the_model_that_runs(monkeypatch, tmp_path):
    real = mediapipe.model_file
    monkeypatch.setattr(mediapipe, "model_file", lambda m: tmp_path / "absent.tflite" if m == "heavy" else real(m))
    src = MediaPipeSource(model="heavy")  # heavy missing: full runs, with full's adapter and guard
    assert src.model == "full" and src.person_guard is guard.for_model("full")
    ref = KeypointAdapter.load(model="full").state_dict()
    assert all(torch.equal(v, ref[k]) for k, v in src.adapter.state_dict().items())


def test_adapter_evaluation_counts_found_images_and_measures_root_relative_joints(tmp_path):
    """``recon keypoints eval``: only the images MediaPipe found count; an adapter that answers zeros
    is off by the distance of each joint to the root."""
    rng = np.random.default_rng(0)
    n = 6
    k = np.tile(np.array([[200.0, 0, 128], [0, 200.0, 128], [0, 0, 1]], np.float32), (n, 1, 1))
    p3 = rng.normal(0, 0.3, (n, 42, 3)).astype(np.float32) + [0, 0, 3]
    xy = rng.uniform(50, 200, (n, mediapipe.NUM_MP, 2)).astype(np.float32)
    found = np.array([True, True, False, True, False, True])
    np.savez(tmp_path / "mp-00000.npz", found=found, xy=xy, world=rng.normal(0, 0.3, (n, 33, 3)).astype(np.float32),
             vis=np.ones((n, 33), np.float32), cut=np.full(n, 256), K=k, points3d=p3,
             points2d=rng.uniform(50, 200, (n, 42, 2)).astype(np.float32))

    class Zeros(torch.nn.Module):
        def forward(self, x):
            return torch.zeros(len(x), 42, 3), torch.zeros(len(x), 42, 2)

    r = train.evaluate(Zeros(), tmp_path)
    rel = (p3 - p3[:, :1])[found][:, :24]
    assert r["samples"] == 4 and r["found_rate"] == pytest.approx(4 / 6)
    assert r["mpjpe_mm"] == pytest.approx(1000 * np.linalg.norm(rel, axis=-1).mean(), rel=1e-5)


@needs_mediapipe
def test_building_each_mediapipe_graph_writes_nothing_to_stderr():
    """The C++ graphs log (INFO, W0000) from their own threads once their calculators open: each model
    is built and run once inside the quiet window, so nothing reaches the terminal afterwards either."""
    code = ("import time, numpy as np\n"
            "from recon.people.mediapipe import MediaPipeLandmarks, MediaPipePose\n"
            "from recon.people.search import PersonMask\n"
            "models = [MediaPipeLandmarks(), MediaPipePose(), PersonMask()]\n"
            "time.sleep(1.0)\n"
            "print('built', len(models))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "built 3" in done.stdout, done.stderr
    assert done.stderr.strip() == "", done.stderr
