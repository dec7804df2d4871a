"""The per-frame pass's two stages: overlapped on two threads (``ahead``), the same results as one
after the other, exceptions and early stops handed across."""
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from recon.video.frames import Frame
from recon.video.perframe import STEP, PerFrame, ahead


def test_ahead_yields_every_item_in_order():
    assert list(ahead(iter(range(50)), depth=2)) == list(range(50))
    assert list(ahead(iter([]))) == []


def test_ahead_raises_the_producer_s_exception_after_its_items():
    def items():
        yield 1
        yield 2
        raise KeyboardInterrupt  # a killed keypoint stage stops the run, as it would without the thread
    got = []
    with pytest.raises(KeyboardInterrupt):
        for x in ahead(items()):
            got.append(x)
    assert got == [1, 2]


def test_ahead_stops_its_thread_when_the_consumer_stops():
    closed = threading.Event()

    def items():
        try:
            yield from range(10_000)
        finally:
            closed.set()
    before = threading.active_count()
    for x in ahead(items()):
        if x == 3:
            break
    assert closed.is_set()  # the producer's generator was closed, on its own thread ...
    assert threading.active_count() == before  # ... and that thread ended


class StageRecorder:
    """Stands in for ``recon.Reconstructor``: one person per frame, made from the frame's number;
    records which thread ran each stage and when."""

    def __init__(self, delay: float = 0.0):
        self.body = SimpleNamespace(num_shape_params=3)
        self.delay = delay
        self.threads = {"find": set(), "from": set()}

    def find_people(self, images, ks, max_people):
        self.threads["find"].add(threading.get_ident())
        time.sleep(self.delay * len(images))
        return [float(rgb[0, 0, 0]) for rgb in images]

    def people_from(self, images, found):
        self.threads["from"].add(threading.get_ident())
        time.sleep(self.delay * len(images))
        out = []
        for f in found:
            kp = SimpleNamespace(points2d=np.full((42, 2), f), points3d=np.full((42, 3), f / 10), confidence=0.5,
                                 mask=None, box=np.array([f, f, f + 20, f + 40]))
            out.append([SimpleNamespace(keypoints=kp, rotmats=np.tile(np.eye(3), (24, 1, 1)), shape=np.full(3, f),
                                        translation=np.array([0.0, 0.0, f]))])
        return out


def _frames(n: int, bad=()):
    out = []
    for i in range(n):
        rgb = np.zeros((32, 32, 3), np.uint8)
        rgb[0, 0, 0] = i
        out.append(Frame(i, i / 30, None if i in bad else rgb, "unreadable" if i in bad else ""))
    return out


@pytest.mark.parametrize("batch", [7, 30])
def test_the_pipelined_pass_equals_the_stages_one_after_the_other(tmp_path, batch):
    frames = _frames(2 * STEP + 5, bad=(4,))
    k = np.eye(3)
    runs = {}
    for pipeline in (False, True):
        rec = StageRecorder()
        boxes = []
        dets, log = PerFrame(rec, k, tmp_path / str(pipeline), batch=batch, pipeline=pipeline).run(
            frames, lambda b, resumed, bx, boxes=boxes: boxes.extend(bx))
        runs[pipeline] = (dets, log, boxes, rec)
    (a, log_a, boxes_a, rec_a), (b, log_b, boxes_b, rec_b) = runs[False], runs[True]
    assert a.frame.tolist() == [f for f in range(len(frames)) if f != 4]
    for name in ("frame", "points2d", "points3d", "box", "rotmats", "shape", "translation"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert log_a == log_b and log_a.error[4] == "unreadable"
    assert [x.tolist() for x in boxes_a] == [x.tolist() for x in boxes_b] and len(boxes_a) == len(frames)
    main = threading.get_ident()
    assert rec_a.threads == {"find": {main}, "from": {main}}
    assert rec_b.threads["from"] == {main} and main not in rec_b.threads["find"]


def test_the_two_stages_overlap(tmp_path):
    frames = _frames(4 * STEP)
    seconds = {}
    for pipeline in (False, True):
        t0 = time.perf_counter()
        PerFrame(StageRecorder(delay=0.005), np.eye(3), tmp_path / str(pipeline), batch=STEP,
                 pipeline=pipeline).run(frames)
        seconds[pipeline] = time.perf_counter() - t0
    # sleeping stages: one after the other 2 x 40 x 5 ms; overlapped about 5/8 of that
    assert seconds[True] < 0.85 * seconds[False], seconds
