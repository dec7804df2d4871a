"""eval/video.py's matching of predictions to true people: a track keeps its person where two
people overlap (CLEAR MOT), and a real swap is still a swap."""
import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np

EVAL = Path(__file__).resolve().parent.parent / "eval"
spec = importlib.util.spec_from_file_location("eval_video", EVAL / "video.py")
eval_video = importlib.util.module_from_spec(spec)
spec.loader.exec_module(eval_video)

K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])


def _person(x: float) -> np.ndarray:
    """(24, 3) joints of a 1.7 m stick person at x metres, 5 m away."""
    return np.stack([np.full(24, x), np.linspace(-0.85, 0.85, 24), np.full(24, 5.0)], 1)


def _truth(xs: list[list[float]]) -> SimpleNamespace:
    joints = np.array([[_person(x) for x in row] for row in xs])  # (P, F, 24, 3)
    return SimpleNamespace(K=K, joints=joints, visible=np.ones(joints.shape[:2], bool))


def _pred(tracks: dict[int, list[float]], frames: int) -> list[list[tuple]]:
    return [[(i, _person(xs[f]), None, None) for i, xs in tracks.items()] for f in range(frames)]


def test_a_track_keeps_its_person_where_two_people_overlap():
    truth = _truth([[-0.4, -0.005, 0.4], [0.4, 0.005, -0.4]])  # they meet in frame 1
    pred = _pred({7: [-0.4, 0.01, 0.4], 9: [0.4, -0.01, -0.4]}, 3)  # each track nearer the other person there
    m = eval_video.match(truth, pred)
    ids = [[pred[f][m[p, f]][0] for f in range(3)] for p in range(2)]
    assert ids == [[7, 7, 7], [9, 9, 9]]


def test_a_real_swap_is_still_matched_by_distance():
    truth = _truth([[-0.6, -0.6, -0.6], [0.6, 0.6, 0.6]])  # apart all along
    pred = _pred({7: [-0.6, 0.6, 0.6], 9: [0.6, -0.6, -0.6]}, 3)  # the tracks exchange people after frame 0
    m = eval_video.match(truth, pred)
    ids = [[pred[f][m[p, f]][0] for f in range(3)] for p in range(2)]
    assert ids == [[7, 9, 9], [9, 7, 7]]
