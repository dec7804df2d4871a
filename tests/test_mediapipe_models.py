"""MediaPipe's three landmark models: chosen by name, a missing file falls back to full (one warning,
no download attempt), an unknown name is refused before anything runs."""
import logging

import numpy as np
import pytest
import skimage.data

from recon.cli import build_parser
from recon.errors import MissingFile, ReconError
from recon.keypoints import mediapipe, train
from recon.pipeline import Reconstructor, ReconstructorConfig

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
    assert parser.parse_args(["run", "--out", "o"]).keypoint_model == "full"
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
