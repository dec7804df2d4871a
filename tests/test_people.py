"""The people stage (recon.people): the TF.js graph reader's conventions against torch written out
by hand, the tiles and NMS, and the shipped detector on the bundled photos (colour, gray, small)."""
import base64
import json

import cv2
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from recon import io
from recon.demo import EXAMPLES
from recon.errors import ReconError
from recon.keypoints import available as mediapipe_available
from recon.people import models
from recon.people.detector import INPUT, PersonDetector, letterbox, nms, tile_grid
from recon.people.tfjs import TFJSGraph, _same_pad, read_weights

needs_detector = pytest.mark.skipif(not models.available("nanodet"),
                                    reason="needs the person detector (scripts/setup.sh installs it)")


def _b64(s: str) -> str:
    return base64.b64encode(s.encode()).decode()


def _graph(tmp_path, w: np.ndarray, b: np.ndarray, stride: int, padding: str, quantise: bool, op="_FusedConv2D"):
    """A one-convolution graph model (NHWC input, HWIO weights, bias + Relu6 fused) written to disk."""
    weights = [{"name": "w", "shape": list(w.shape), "dtype": "float32"},
               {"name": "b", "shape": list(b.shape), "dtype": "float32"}]
    if quantise:  # uint8 affine quantisation of the kernel, float16 of the bias, as the converter writes
        lo, scale = float(w.min()), float(w.max() - w.min()) / 255
        q = np.round((w - lo) / scale).astype(np.uint8)
        weights[0]["quantization"] = {"dtype": "uint8", "min": lo, "scale": scale}
        weights[1]["quantization"] = {"dtype": "float16"}
        data = q.tobytes() + b.astype("<f2").tobytes()
        w = q.astype(np.float32) * np.float32(scale) + np.float32(lo)
    else:
        data = w.astype("<f4").tobytes() + b.astype("<f4").tobytes()
    (tmp_path / "m.bin").write_bytes(data)
    conv = {"name": "conv", "op": op, "input": ["x", "w", "b"],
            "attr": {"strides": {"list": {"i": ["1", str(stride), str(stride), "1"]}},
                     "padding": {"s": _b64(padding)}, "data_format": {"s": _b64("NHWC")},
                     "dilations": {"list": {"i": ["1", "1", "1", "1"]}},
                     "fused_ops": {"list": {"s": [_b64("BiasAdd"), _b64("Relu6")]}}}}
    graph = {"format": "graph-model", "modelTopology": {"node": [
        {"name": "x", "op": "Placeholder"}, {"name": "w", "op": "Const"}, {"name": "b", "op": "Const"}, conv,
        {"name": "Identity", "op": "Identity", "input": ["conv"]}]},
        "signature": {"outputs": {"y": {"name": "Identity:0"}}},
        "weightsManifest": [{"paths": ["m.bin"], "weights": weights}]}
    (tmp_path / "m.json").write_text(json.dumps(graph))
    return tmp_path / "m.json", w


def test_same_padding_puts_the_odd_pixel_after_as_tensorflow_does():
    assert _same_pad(5, 3, 2, 1) == (1, 1)
    assert _same_pad(4, 3, 2, 1) == (0, 1)
    assert _same_pad(416, 3, 2, 1) == (0, 1)
    assert _same_pad(7, 1, 1, 1) == (0, 0)


@pytest.mark.parametrize("quantise", [False, True])
@pytest.mark.parametrize("stride,padding", [(1, "SAME"), (2, "SAME"), (2, "VALID")])
def test_a_fused_convolution_equals_torch_written_out(tmp_path, stride, padding, quantise):
    rng = np.random.default_rng(0)
    w = rng.normal(0, 0.5, (3, 3, 4, 6)).astype(np.float32)  # HWIO
    b = rng.normal(0, 0.5, 6).astype(np.float32)
    path, w_used = _graph(tmp_path, w, b, stride, padding, quantise)
    x = torch.from_numpy(rng.normal(0, 1, (1, 8, 8, 4)).astype(np.float32))
    y = TFJSGraph.load(path)(x)["Identity"]
    xc = x.permute(0, 3, 1, 2)
    if padding == "SAME":  # TensorFlow: total padding split with the extra pixel at the end
        t, bt = _same_pad(8, 3, stride, 1)
        xc = F.pad(xc, (t, bt, t, bt))
    b_used = torch.from_numpy(b.astype(np.float16).astype(np.float32) if quantise else b)
    ref = F.relu6(F.conv2d(xc, torch.from_numpy(w_used).permute(3, 2, 0, 1), b_used, stride=stride))
    assert y.shape == ref.permute(0, 2, 3, 1).shape
    torch.testing.assert_close(y, ref.permute(0, 2, 3, 1), atol=1e-5, rtol=1e-5)


def test_a_depthwise_convolution_groups_by_channel(tmp_path):
    rng = np.random.default_rng(1)
    w = rng.normal(0, 0.5, (3, 3, 4, 1)).astype(np.float32)  # H, W, C, multiplier
    b = np.zeros(4, np.float32)
    path, _ = _graph(tmp_path, w, b, 1, "SAME", False, op="FusedDepthwiseConv2dNative")
    x = torch.from_numpy(rng.normal(0, 1, (1, 6, 6, 4)).astype(np.float32))
    y = TFJSGraph.load(path)(x)["Identity"]
    # channel c only sees channel c: zeroing channel 0 of the input changes only output channel 0
    x2 = x.clone()
    x2[..., 0] = 0
    y2 = TFJSGraph.load(path)(x2)["Identity"]
    assert not torch.allclose(y[..., 0], y2[..., 0]) and torch.equal(y[..., 1:], y2[..., 1:])


def test_a_graph_with_an_unknown_operation_or_no_file_is_refused(tmp_path):
    path, _ = _graph(tmp_path, np.zeros((1, 1, 1, 1), np.float32), np.zeros(1, np.float32), 1, "SAME", False)
    g = json.loads(path.read_text())
    g["modelTopology"]["node"][3]["op"] = "NonMaxSuppressionV5"
    path.write_text(json.dumps(g))
    with pytest.raises(ReconError, match="NonMaxSuppressionV5"):
        TFJSGraph.load(path)
    with pytest.raises(ReconError, match="not found"):
        TFJSGraph.load(tmp_path / "missing.json")


def test_a_manifest_that_does_not_match_its_shard_is_refused(tmp_path):
    (tmp_path / "m.bin").write_bytes(b"\0" * 12)
    with pytest.raises(ReconError, match="12 bytes"):
        read_weights([{"paths": ["m.bin"], "weights": [{"name": "w", "shape": [2], "dtype": "float32"}]}], tmp_path)


def test_tiles_cover_the_image_and_overlap():
    h, w = 768, 1024
    tiles = tile_grid(h, w, 0.6)
    cover = np.zeros((h, w), bool)
    for x0, y0, x1, y1 in tiles:
        assert x1 - x0 == y1 - y0 == round(0.6 * h)
        cover[y0:y1, x0:x1] = True
    assert cover.all()
    assert tile_grid(100, 100, 1.0) == [(0, 0, 100, 100)]


def test_nms_keeps_the_best_of_overlapping_boxes_and_separate_ones():
    boxes = np.array([[0, 0, 10, 20], [1, 0, 11, 20], [30, 0, 40, 20]], float)
    assert nms(boxes, np.array([0.5, 0.9, 0.4]), 0.5) == [1, 2]
    assert nms(np.zeros((0, 4)), np.zeros(0), 0.5) == []


def test_letterbox_keeps_the_aspect_and_pads_below_and_right():
    img, s = letterbox(np.full((200, 400, 3), 255, np.uint8))
    assert img.shape == (INPUT, INPUT, 3) and s == INPUT / 400
    assert img[:INPUT // 2 - 1].min() == 255 and img[INPUT // 2 + 1:].max() == 0


@pytest.fixture(scope="module")
def detector():
    return PersonDetector()


@needs_detector
def test_the_detector_finds_the_person_of_each_colour_and_gray_photo(detector):
    astronaut = io.load_image(EXAMPLES / "astronaut.jpg")
    gray = np.repeat(cv2.cvtColor(astronaut, cv2.COLOR_RGB2GRAY)[..., None], 3, 2)
    for rgb in (astronaut, gray, io.load_image(EXAMPLES / "cameraman.png")):
        found = detector(rgb)
        assert found, "nobody found"
        best = max(found, key=lambda d: d.score)
        h, w = rgb.shape[:2]
        # the person is the photo's subject: a box of at least half its height, centred in its middle half
        assert best.height > 0.5 * h and 0.25 * w < 0.5 * (best.box[0] + best.box[2]) < 0.75 * w


@needs_detector
def test_the_detector_finds_nobody_in_flat_or_noise_images(detector):
    rng = np.random.default_rng(0)
    for rgb in (np.full((480, 640, 3), 128, np.uint8), rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)):
        assert [d for d in detector(rgb) if d.score > 0.35] == []


@needs_detector
def test_tiles_find_a_small_person_the_whole_view_misses(detector):
    """The astronaut 110 px tall in a 1600 x 1200 scene: 38 px in the detector's whole view."""
    person = cv2.resize(io.load_image(EXAMPLES / "astronaut.jpg"), (110, 110), interpolation=cv2.INTER_AREA)
    scene = np.full((1200, 1600, 3), 90, np.uint8)
    scene[700:810, 900:1010] = person
    whole = PersonDetector(tiles=())(scene)
    tiled = detector(scene)
    hit = [d for d in tiled if d.box[0] < 1010 and d.box[2] > 900 and d.box[1] < 810 and d.box[3] > 700]
    assert hit and max(d.score for d in hit) > max([d.score for d in whole] + [0.0])


@needs_detector
@pytest.mark.skipif(not mediapipe_available(), reason="needs mediapipe (scripts/setup.sh)")
def test_two_people_side_by_side_are_both_read_and_a_wall_gives_nobody():
    from recon.keypoints.sources import MediaPipeSource

    src = MediaPipeSource(detect=True)
    person = io.load_image(EXAMPLES / "astronaut.jpg")
    pair = np.concatenate([person, person[:, ::-1]], 1)
    k = np.array([[800.0, 0, pair.shape[1] / 2], [0, 800.0, pair.shape[0] / 2], [0, 0, 1]])
    people = src.people(pair, k, 5)
    assert len(people) == 2
    centres = sorted(0.5 * (p.box[0] + p.box[2]) for p in people)
    assert centres[0] < pair.shape[1] / 2 < centres[1]
    assert all(p.found_by.startswith("mediapipe-") for p in people)
    wall = np.full((480, 640, 3), 128, np.uint8)
    assert src.detected(wall, k, 5) == []


def test_fusion_weighs_each_keypoint_by_its_models_confidence_and_hands_follow_wrists():
    from recon.keypoints.movenet import FOLLOW, TO_MEDIAPIPE, fuse
    from recon.people.mediapipe import MPPose

    rng = np.random.default_rng(0)
    r = MPPose(rng.uniform(0, 100, (33, 2)), np.full(33, 0.5), rng.normal(0, 1, (33, 3)), None)
    xy = r.image_xy[list(TO_MEDIAPIPE)] + 10.0
    score = np.full(17, 0.5)
    assert np.array_equal(fuse(r, xy, score, 0.0).image_xy, r.image_xy)  # weight 0: MediaPipe's alone
    f = fuse(r, xy, score, 1.0)  # equal confidence: halfway
    np.testing.assert_allclose(f.image_xy[list(TO_MEDIAPIPE)], r.image_xy[list(TO_MEDIAPIPE)] + 5.0)
    wrist = TO_MEDIAPIPE.index(15)
    np.testing.assert_allclose(f.image_xy[list(FOLLOW[15])], r.image_xy[list(FOLLOW[15])] + 5.0)
    untouched = sorted(set(range(33)) - set(TO_MEDIAPIPE) - {i for v in FOLLOW.values() for i in v})
    assert np.array_equal(f.image_xy[untouched], r.image_xy[untouched])
    score[wrist] = 0.0  # MoveNet unsure of the wrist: MediaPipe's stays
    np.testing.assert_allclose(fuse(r, xy, score, 1.0).image_xy[15], r.image_xy[15])
    assert np.array_equal(f.world, r.world) and np.array_equal(f.visibility, r.visibility)


def test_an_answers_score_is_the_sum_of_its_votes_each_zero_at_its_reference():
    from recon.keypoints.on_boxes import DETECTOR_REF, MOVENET_REF, Reading, box_roi, logit, movenet_term

    assert logit(DETECTOR_REF) - logit(DETECTOR_REF) == 0.0 and movenet_term(MOVENET_REF) == pytest.approx(0.0)
    assert logit(0.5) == pytest.approx(0.0) and logit(0.9) > logit(0.3)
    assert np.isfinite(logit(1.0)) and np.isfinite(logit(0.0)) and np.isfinite(movenet_term(0.0))
    assert movenet_term(0.6) > 0 > movenet_term(0.1)  # a body MoveNet sees votes for, a wall against
    r = Reading(None, {"guard": 0.7, "detector": -0.2, "movenet": 1.0}, None)
    assert r.score == pytest.approx(1.5) and r.score_alone == pytest.approx(0.5)
    assert box_roi((10, 20, 30, 100)) == pytest.approx((20, 60, 100, 0))


def test_the_first_person_needs_the_guard_and_detector_further_people_all_three_votes():
    from recon.keypoints.on_boxes import MIN_SCORE, MIN_SCORE_ALONE, Reading, is_person

    misread = Reading(None, {"guard": MIN_SCORE_ALONE, "detector": 0.1, "movenet": -1.5}, None)  # a lone, cut person
    assert is_person(misread, first=True) and not is_person(misread, first=False)
    wall = Reading(None, {"guard": 0.5, "detector": 0.2, "movenet": -2.0}, None)
    assert not is_person(wall, first=True)
    seen_by_all = Reading(None, {"guard": 0.2, "detector": 0.3, "movenet": MIN_SCORE}, None)
    assert is_person(seen_by_all, first=False) and is_person(seen_by_all, first=True)
    assert is_person(Reading(None, {"guard": 1.2, "detector": -0.1}, None), bar=MIN_SCORE_ALONE)  # no MoveNet


@needs_detector
@pytest.mark.skipif(not models.available("movenet-thunder"), reason="needs MoveNet (scripts/setup.sh)")
def test_movenet_reads_the_astronauts_face_and_shoulders_where_they_are():
    from recon.keypoints.movenet import MoveNet

    rgb = io.load_image(EXAMPLES / "astronaut.jpg")
    xy, score = MoveNet()(rgb, (60.0, 0.0, 400.0, 512.0))
    assert xy.shape == (17, 2) and score.shape == (17,)
    assert score[:7].min() > 0.4  # nose, eyes, ears, shoulders: in view
    # the face above the shoulders, the person's left eye on the image's right (she faces us)
    assert xy[0, 1] < xy[5:7, 1].min() and xy[1, 0] > xy[2, 0]


@pytest.mark.skipif(not mediapipe_available(), reason="needs mediapipe (scripts/setup.sh)")
def test_without_the_installed_models_recon_run_falls_back_to_mediapipes_detector(tmp_path, monkeypatch):
    from recon.pipeline import Reconstructor

    monkeypatch.setenv("RECON_PEOPLE_MODELS", str(tmp_path))  # an empty folder: nothing installed
    rec = Reconstructor()
    assert rec.config.detect is False and rec.config.movenet == 0.0
    assert rec.source.detect is False and rec.source.movenet == 0.0
    assert rec(io.load_image(EXAMPLES / "astronaut.jpg")).keypoints.found_by == "mediapipe"
