"""The camera's turn from the background (recon.video.camera_motion): a textured far background
seen by a panning and tilting camera (exact homographies), people moving across it masked out; and
the shapes of the failures a still camera must not be read as turning from: a person filling the
frame with a few noisy columns of background left, two people, a glitched frame."""
import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from recon.video.camera_motion import (
    MIN_MEASURED,
    CameraRotations,
    TurnEstimate,
    background_mask,
    fill_unknown,
    kabsch,
    ransac_rotation,
    spread,
    turned_degrees,
)

K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
K_REF = np.array([[600.0, 0, 640], [0, 600.0, 480], [0, 0, 1]])  # the panorama's camera (the first frame's)


def _panorama(seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.random((960, 1280)).astype(np.float32), (0, 0), 3)
    img = cv2.normalize(noise, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return np.repeat(img[..., None], 3, axis=2)


def _view(pano, r, k=K, size=(480, 640)):
    h = K_REF @ r.T @ np.linalg.inv(k)  # frame pixel -> panorama pixel
    return cv2.warpPerspective(pano, h, size[::-1], flags=cv2.WARP_INVERSE_MAP | cv2.INTER_LINEAR)


def _person(frame, box, t, seed):
    """Paints a person over ``box``: a texture of its own that moves with it and changes frame to frame."""
    x0, y0, x1, y1 = np.asarray(box).astype(int)
    tex = _panorama(seed)[:y1 - y0, 3 * t:3 * t + x1 - x0]
    frame[y0:y1, x0:x1] = tex // 2 + 60 + (5 * t) % 40


def _clip(rotations, person=False):
    """Frames of the panorama seen by cameras turned by ``rotations`` (x_t = R_t x_0); with
    ``person`` a textured block sliding right across the middle, and its boxes."""
    pano, frames, boxes = _panorama(), [], []
    for t, r in enumerate(rotations):
        f = _view(pano, r)
        box = np.array([[200 + 12 * t, 150, 300 + 12 * t, 420]], float)
        if person:
            _person(f, box[0], t, 1)
        frames.append(f)
        boxes.append(box)
    return frames, boxes


def _turns(n=12, rate=1.0):
    """A pan of 0.5 degrees a frame with a slow tilt and some roll (times ``rate``)."""
    return [Rotation.from_euler("yxz", [0.5 * rate * t, 0.2 * rate * t, 0.05 * rate * t], degrees=True).as_matrix()
            for t in range(n)]


def _angle(a, b):
    return np.degrees(np.arccos(np.clip((np.trace(a @ b.T) - 1) / 2, -1, 1)))


def _errors(found: TurnEstimate, truth) -> list[float]:
    return [_angle(f, t) for f, t in zip(found.rotations, truth, strict=True)]


@pytest.mark.parametrize("person", [False, True])
def test_a_panning_camera_s_turn_is_found_with_a_person_masked_out(person):
    truth = _turns()
    frames, boxes = _clip(truth, person)
    found = CameraRotations(K)(zip(frames, boxes if person else [None] * len(frames), strict=True))
    assert found.rotations.shape == (12, 3, 3) and found.points[0] == 0 and (found.points[1:] >= 20).all()
    assert not found.measured[0] and found.measured[1:].all() and found.known and found.turned
    errors = _errors(found, truth)
    assert max(errors) < 0.2, errors  # degrees, after 11 steps at 320 px (drift included)
    assert found.degrees == pytest.approx(turned_degrees(np.stack(truth)), abs=0.2)


def test_a_pan_with_most_of_its_background_covered_is_still_measured():
    """Two people cover 60 % of the frame's width and move; the pan is measured on the rest."""
    truth = _turns(30)
    pano, frames, boxes = _panorama(), [], []
    for t, r in enumerate(truth):
        f = _view(pano, r)
        people = np.array([[60 + 4 * t, 40, 260 + 4 * t, 480], [300 - 3 * t, 60, 480 - 3 * t, 480]], float)
        for n, b in enumerate(people):
            _person(f, b, t, 2 + n)
        frames.append(f)
        boxes.append(people)
    found = CameraRotations(K)(zip(frames, boxes, strict=True))
    assert found.measured_share > 0.9 and found.turned
    assert max(_errors(found, truth)) < 0.2


def test_a_still_camera_does_not_turn_and_a_blank_frame_is_no_turn():
    frames, boxes = _clip([np.eye(3)] * 4, person=True)
    found = CameraRotations(K)(zip(frames, boxes, strict=True))
    assert found.degrees < 0.02 and found.known and not found.turned
    blank = [np.full((480, 640, 3), 128, np.uint8)] * 3
    found = CameraRotations(K)((b, None) for b in blank)
    assert np.allclose(found.rotations, np.eye(3)) and (found.points == 0).all()
    assert not found.measured.any() and found.measured_share == 0.0 and not found.known


def _filled_frame(t, pano, k, size, boxes):
    """A still camera's frame with people filling it: each box painted with its own moving texture,
    an arm (a textured patch) swinging beside the first box, beyond its grown edge, over the
    background, and fresh sensor noise."""
    f = _view(pano, np.eye(3), k, size)
    for n, b in enumerate(boxes):
        _person(f, b, t, 3 + n)
    x0, y0, x1, y1 = boxes[0]
    x = int(x1 + 0.1 * max(x1 - x0, y1 - y0)) + 1 + int(4 * np.sin(t / 2))
    y = int(y0 + 0.4 * (y1 - y0) + 30 * np.sin(t / 3))
    f[y:y + 40, x:x + 8] = _panorama(7)[2 * t:2 * t + 40, :8][:, :max(0, f.shape[1] - x)] // 3 + 120
    grain = np.random.default_rng(t).normal(0, 2.0, f.shape)
    return np.clip(f + grain, 0, 255).astype(np.uint8)


def test_a_still_camera_with_a_person_filling_the_frame_is_not_read_as_turning():
    """A portrait clip (the failure's shape): the walker's box, grown by 10 %, leaves a few columns of
    background at one side, some of them covered by a swinging arm outside the box."""
    size, k = (320, 240), np.array([[300.0, 0, 120], [0, 300.0, 160], [0, 0, 1]])
    pano, frames, boxes = _panorama(), [], []
    for t in range(60):
        box = np.array([[12 + (t % 7) * 0.3, 10, 200 + (t % 5) * 0.4, 320]], float)
        frames.append(_filled_frame(t, pano, k, size, box))
        boxes.append(box)
    assert background_mask(size, boxes[0]).any(axis=0).sum() <= 10  # a few columns of background
    found = CameraRotations(k)(zip(frames, boxes, strict=True))
    assert found.degrees < 1.0 and not found.turned


def test_a_still_camera_with_two_people_is_not_read_as_turning():
    """Two people near the camera walk towards each other, each 40 % of the frame's width."""
    pano, frames, boxes = _panorama(), [], []
    for t in range(60):
        people = np.array([[10 + 3 * t, 30, 270 + 3 * t, 480], [360 - 3 * t, 50, 620 - 3 * t, 480]], float)
        frames.append(_filled_frame(t, pano, K, (480, 640), people))
        boxes.append(people)
    found = CameraRotations(K)(zip(frames, boxes, strict=True))
    assert found.degrees < 1.0 and not found.turned


@pytest.mark.parametrize("glitch", [4.0, 25.0])
def test_a_glitched_frame_is_not_a_turn_and_the_pan_goes_on(glitch):
    """One frame decoded wrong (another part of the scene, ``glitch`` degrees away): near enough to
    be matched, both its steps are spikes (there and back in 1/30 s) and are filled from their
    neighbours; too far, it is not matched and the next frame is measured across it."""
    truth = _turns(20)
    frames, _ = _clip(truth)
    frames[10] = _view(_panorama(), Rotation.from_euler("y", glitch, degrees=True).as_matrix() @ truth[10])
    found = CameraRotations(K)((f, None) for f in frames)
    if glitch < 10:
        assert not found.measured[10] and not found.measured[11]
    assert found.measured_share > 0.85
    errors = _errors(found, truth)
    assert max(errors) < 0.3, errors


def test_a_frame_that_could_not_be_read_is_bridged():
    truth = _turns(6)
    frames, _ = _clip(truth)
    cam = CameraRotations(K)
    for n, f in enumerate(frames):
        cam.hold() if n == 3 else cam.add(f, None)
    found = cam.result()
    assert found.rotations.shape == (6, 3, 3) and found.known
    assert max(_errors(found, truth)) < 0.2  # frame 4 measured against the key, across frame 3


def test_the_limits_on_a_step_are_per_second():
    """Every third frame of a pan at 10 frames/s: steps three times larger, the same turn."""
    truth = _turns(31)[::3]
    frames, _ = _clip(truth)
    found = CameraRotations(K, fps=10.0)((f, None) for f in frames)
    assert found.measured[1:].all() and max(_errors(found, truth)) < 0.2
    too_fast = CameraRotations(K, fps=10.0, max_degrees_per_second=3.0)((f, None) for f in frames)
    assert not too_fast.measured.any() and too_fast.degrees == 0.0  # 0.54 degrees a step: 5.4 a second


def test_unknown_steps_are_interpolated_between_measured_ones_or_taken_as_still():
    rates = np.array([[1.0, 0, 0], [9, 9, 9], [9, 9, 9], [2, 0, 0], [0, 0, 3], [9, 9, 9]])
    ok = np.array([True, False, False, True, True, False])
    out = fill_unknown(rates, ok, max_gap=3)
    assert np.allclose(out[1:3, 0], [4 / 3, 5 / 3]) and np.allclose(out[1:3, 1:], 0)
    assert np.allclose(out[5], 0)  # no measured step after it: still
    assert np.allclose(fill_unknown(rates, ok, max_gap=2)[1:3], 0)  # the gap too long: still


def test_a_clip_measured_on_few_steps_is_not_known():
    measured = np.zeros(11, bool)
    measured[1:6] = True
    est = TurnEstimate(np.repeat(np.eye(3)[None], 11, 0), np.zeros(11, int), measured)
    assert est.measured_share == pytest.approx(0.5) and est.known == (0.5 >= MIN_MEASURED)
    measured[5] = False
    assert not TurnEstimate(est.rotations, est.points, measured).known
    single = TurnEstimate(np.eye(3)[None], np.zeros(1, int), np.zeros(1, bool))
    assert single.measured_share == 1.0 and single.degrees == 0.0


def test_ransac_rotation_ignores_a_moving_cluster():
    rng = np.random.default_rng(0)
    r = Rotation.from_euler("yxz", [2.0, -1.0, 0.5], degrees=True).as_matrix()
    p0 = rng.uniform([0, 0], [640, 480], (200, 2))
    x = np.concatenate([p0, np.ones((200, 1))], 1) @ np.linalg.inv(K).T @ r.T @ K.T
    p1 = x[:, :2] / x[:, 2:] + rng.normal(0, 0.2, (200, 2))
    p1[:60] += [25.0, -10.0]  # a person's points, moving together
    found, inliers = ransac_rotation(p0, p1, K, px=1.0)
    assert _angle(found, r) < 0.02 and not inliers[:60].any() and inliers[60:].mean() > 0.95


def test_helpers():
    mask = background_mask((100, 200), np.array([[50, 20, 70, 60]]), grow=0.0)
    assert not mask[30, 60] and mask[10, 10] and mask.sum() == 100 * 200 - 21 * 41
    a = Rotation.random(3, random_state=1)
    v = np.random.default_rng(2).normal(size=(3, 10, 3))
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    b = np.stack([a[i].apply(v[i]) for i in range(3)])
    assert np.allclose(kabsch(v, b), a.as_matrix(), atol=1e-9)
    assert np.allclose(np.linalg.det(kabsch(v, -b)), 1.0)  # a rotation, never a reflection
    column = np.stack([np.full(50, 300.0), np.linspace(0, 470, 50)], 1)
    assert spread(column, (480, 640))[0] < 0.01 and spread(column, (480, 640))[1] > 0.7


def _travelling(n=12, metres_per_frame=0.02, depth=3.0, sway=None):
    """A camera sliding sideways (``sway``: to and fro this many metres, once in 3 s): the top half
    far away (it does not shift), the bottom half a textured wall ``depth`` metres off (it shifts by
    f * move / depth pixels: parallax)."""
    far, near = _panorama(0), _panorama(5)
    frames = []
    for t in range(n):
        f = _view(far, np.eye(3))
        place = sway * np.sin(2 * np.pi * t / 90) if sway else metres_per_frame * t
        shift = K[0, 0] * place / depth
        wall = cv2.warpAffine(_view(near, np.eye(3)), np.float32([[1, 0, -shift], [0, 1, 0]]), (640, 480))
        f[240:] = wall[240:]
        frames.append(f)
    return frames


def test_a_camera_that_moved_is_told_from_one_that_only_turned():
    moved = CameraRotations(K)((f, None) for f in _travelling())
    assert moved.travelled and np.median(moved.parallax) > 0.3
    # 2 cm a frame 3 m off: f * 0.02 / 3 px a frame, 0.2 radians a second, as measured from the key frames
    assert np.median(moved.rates) == pytest.approx(0.02 / 3.0 * 30.0, rel=0.25)
    swayed = CameraRotations(K)((f, None) for f in _travelling(90, sway=0.05))  # a hand-held camera's drift
    assert (swayed.parallax > 0.1).mean() > 0.2 and np.median(swayed.rates[swayed.parallax > 0]) < 0.015
    assert not swayed.travelled
    turned = CameraRotations(K)((f, None) for f in _clip(_turns())[0])
    assert not turned.travelled and turned.turned and np.median(turned.parallax) < 0.05
    still = CameraRotations(K)((f, None) for f in _travelling(metres_per_frame=0.0))
    assert not still.travelled and not still.turned
    blank = CameraRotations(K)((np.full((480, 640, 3), 128, np.uint8), None) for _ in range(3))
    assert len(blank.parallax) == 0 and not blank.travelled
