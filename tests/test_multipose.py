"""MoveNet MultiPose (recon.people.multipose): the TF.js operations its graph needs, each against
TensorFlow's documented semantics written out by hand, and the shipped model on the bundled photos."""
import json

import numpy as np
import pytest
import torch

from recon import io
from recon.demo import EXAMPLES
from recon.keypoints import available as mediapipe_available
from recon.people import models
from recon.people.detector import Detection
from recon.people.multipose import MultiPoseDetector, new_boxes
from recon.people.tfjs import OPS, TFJSGraph

needs_multipose = pytest.mark.skipif(not models.available("movenet-multipose"),
                                     reason="needs MoveNet MultiPose (scripts/setup.sh installs it)")


def _node(op: str, **attr) -> dict:
    """A node with integer / bool attributes as the TF.js JSON writes them."""
    return {"name": op, "op": op, "attr": {k: {"b": v} if isinstance(v, bool) else {"i": str(v)}
                                           for k, v in attr.items()}}


def _slice(x, begin, end, strides=None, **masks):
    strides = strides or [1] * len(begin)
    return OPS["StridedSlice"](_node("StridedSlice", **masks), [x, torch.tensor(begin), torch.tensor(end),
                                                                torch.tensor(strides)])


def test_strided_slice_follows_each_mask_as_tensorflow_does():
    x = torch.arange(24).reshape(2, 3, 4)
    # begin_mask / end_mask bit i: axis i from its start / to its end, whatever begin / end say
    assert torch.equal(_slice(x, [1, 1, 0], [0, 3, 4], [1, 1, 2], begin_mask=1, end_mask=1), x[:, 1:3, 0:4:2])
    # shrink_axis_mask: that axis indexed (and removed), as x[1]
    assert torch.equal(_slice(x, [1], [2], shrink_axis_mask=1), x[1])
    assert torch.equal(_slice(x, [0, 2], [2, 3], shrink_axis_mask=2, begin_mask=1, end_mask=1), x[:, 2])
    # new_axis_mask: a new axis of size 1 at that place of the spec, as x[:, None, :]
    y = _slice(x, [0, 0, 0], [0, 0, 0], new_axis_mask=2, begin_mask=5, end_mask=5)
    assert y.shape == (2, 1, 3, 4) and torch.equal(y, x[:, None, :])
    with pytest.raises(Exception, match="negative stride"):
        _slice(x, [2], [0], [-1])


def test_reductions_top_k_select_split_and_shape_ops():
    x = torch.tensor([[3.0, 1.0, 2.0], [0.0, 5.0, 4.0]])
    assert torch.equal(OPS["Sum"](_node("Sum", keep_dims=False), [x, torch.tensor(-1)]), torch.tensor([6.0, 9.0]))
    assert OPS["Max"](_node("Max", keep_dims=True), [x, torch.tensor([0, 1])]).shape == (1, 1)
    values, idx = OPS["TopKV2"](_node("TopKV2", sorted=True), [x, torch.tensor(2)])
    assert torch.equal(values, torch.tensor([[3.0, 2.0], [5.0, 4.0]]))
    assert torch.equal(idx, torch.tensor([[0, 2], [1, 2]]))
    # Select with a vector condition picks whole rows (TensorFlow's Select), else elementwise
    rows = OPS["Select"]({}, [torch.tensor([True, False]), x, -x])
    assert torch.equal(rows, torch.stack([x[0], -x[1]]))
    assert torch.equal(OPS["Select"]({}, [x > 2, x, torch.zeros_like(x)]), torch.where(x > 2, x, 0.0))
    a, b, c = OPS["Split"](_node("Split", num_split=3), [torch.tensor(1), x])
    assert torch.equal(b, x[:, 1:2]) and c.shape == (2, 1)
    assert OPS["Shape"]({}, [x]).tolist() == [2, 3] and int(OPS["Size"]({}, [x])) == 6
    assert torch.equal(OPS["Fill"]({}, [torch.tensor([2, 2]), torch.tensor(7)]), torch.full((2, 2), 7))
    assert OPS["Range"]({}, [torch.tensor(0), torch.tensor(6), torch.tensor(2)]).tolist() == [0, 2, 4]
    assert OPS["Tile"]({}, [x, torch.tensor([2, 1])]).shape == (4, 3)
    assert torch.equal(OPS["AddN"]({}, [x, x, x]), 3 * x)


def test_a_scalar_constant_stays_a_scalar(tmp_path):
    """numpy's ascontiguousarray makes 0-d arrays 1-d; Pack of scalars must still give a vector."""
    (tmp_path / "m.bin").write_bytes(np.array([4], "<i4").tobytes())
    graph = {"format": "graph-model", "modelTopology": {"node": [
        {"name": "x", "op": "Placeholder"}, {"name": "c", "op": "Const"},
        {"name": "size", "op": "Size", "input": ["x"]},
        {"name": "pack", "op": "Pack", "input": ["size", "c"], "attr": {"axis": {"i": "0"}}}]},
        "signature": {"outputs": {"y": {"name": "pack:0"}}},
        "weightsManifest": [{"paths": ["m.bin"], "weights": [{"name": "c", "shape": [], "dtype": "int32"}]}]}
    (tmp_path / "m.json").write_text(json.dumps(graph))
    assert TFJSGraph.load(tmp_path / "m.json")(torch.zeros(3, 2))["pack"].tolist() == [6, 4]


def test_each_detector_votes_against_its_own_reference_score():
    from recon.keypoints.on_boxes import DETECTOR_REF, MULTIPOSE_REF, detector_term

    assert detector_term(DETECTOR_REF, "image") == 0.0 == detector_term(DETECTOR_REF, "tile")
    assert detector_term(MULTIPOSE_REF, "multipose") == 0.0
    assert detector_term(0.9, "multipose") > 0 > detector_term(0.1, "multipose")


def test_new_boxes_are_those_overlapping_no_known_box():
    known = [Detection((0, 0, 100, 200), 0.9)]
    same = Detection((5, 0, 100, 200), 0.5, "multipose")  # IoU 0.95: the same person
    behind = Detection((60, 0, 160, 200), 0.4, "multipose")  # IoU 0.25: someone beside or behind
    assert new_boxes([same, behind], known) == [behind]
    assert new_boxes([same], known, overlap=1.0) == [same]


@pytest.fixture(scope="module")
def multipose():
    return MultiPoseDetector(size=256)


@needs_multipose
def test_multipose_finds_each_of_two_people_and_nobody_on_a_wall(multipose):
    person = io.load_image(EXAMPLES / "astronaut.jpg")
    pair = np.concatenate([person, person[:, ::-1]], 1)
    found = [d for d in multipose(pair) if d.score > 0.3]
    assert len(found) == 2 and all(d.view == "multipose" for d in found)
    centres = sorted(0.5 * (d.box[0] + d.box[2]) for d in found)
    assert centres[0] < pair.shape[1] / 2 < centres[1]
    assert all(0 <= d.box[0] < d.box[2] <= pair.shape[1] and 0 <= d.box[1] < d.box[3] <= pair.shape[0] for d in found)
    assert [d for d in multipose(np.full((480, 640, 3), 128, np.uint8)) if d.score > 0.3] == []
    with pytest.raises(ValueError, match="multiple of 32"):
        MultiPoseDetector(size=300)


@needs_multipose
@pytest.mark.skipif(not mediapipe_available(), reason="needs mediapipe (scripts/setup.sh)")
def test_multipose_runs_only_where_more_than_one_person_is_wanted(monkeypatch):
    from recon.keypoints.sources import MediaPipeSource

    calls = []
    original = MultiPoseDetector.__call__
    monkeypatch.setattr(MultiPoseDetector, "__call__", lambda self, rgb: calls.append(1) or original(self, rgb))
    src = MediaPipeSource(detect=True, multipose=True)
    rgb = io.load_image(EXAMPLES / "astronaut.jpg")
    k = np.array([[500.0, 0, rgb.shape[1] / 2], [0, 500.0, rgb.shape[0] / 2], [0, 0, 1]])
    assert len(src.people(rgb, k, 1)) == 1 and calls == []
    assert len(src.people(rgb, k, 5)) == 1 and calls == [1]  # its box is the same person: read once


@needs_multipose
@pytest.mark.skipif(not mediapipe_available(), reason="needs mediapipe (scripts/setup.sh)")
def test_where_nanodet_gives_nobody_multipose_boxes_are_read_before_mediapipes_detector(monkeypatch):
    from recon.keypoints.sources import MediaPipeSource
    from recon.people.detector import PersonDetector

    monkeypatch.setattr(PersonDetector, "__call__", lambda self, rgb: [])
    person = io.load_image(EXAMPLES / "astronaut.jpg")
    rgb = np.concatenate([person, person[:, ::-1]], 1)  # MultiPose scores a lone head-and-shoulders portrait low
    k = np.array([[500.0, 0, rgb.shape[1] / 2], [0, 500.0, rgb.shape[0] / 2], [0, 0, 1]])
    found = MediaPipeSource(detect=True, multipose=True).people(rgb, k, 1)
    assert len(found) == 1 and found[0].found_by == "mediapipe-multipose"
    assert MediaPipeSource(detect=True, multipose=False).people(rgb, k, 1)[0].found_by != "mediapipe-multipose"
