"""The camera's turn from the background (recon.video.camera_motion): a textured far background
seen by a panning and tilting camera (exact homographies), a person moving across it masked out."""
import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from recon.video.camera_motion import CameraRotations, background_mask, nearest_rotation, turned_degrees

K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
K_REF = np.array([[600.0, 0, 640], [0, 600.0, 480], [0, 0, 1]])  # the panorama's camera (the first frame's)


def _panorama(seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.random((960, 1280)).astype(np.float32), (0, 0), 3)
    img = cv2.normalize(noise, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return np.repeat(img[..., None], 3, axis=2)


def _clip(rotations, person=False):
    """Frames of the panorama seen by cameras turned by ``rotations`` (x_t = R_t x_0); with
    ``person`` a bright block sliding right across the middle, and its boxes."""
    pano, frames, boxes = _panorama(), [], []
    for t, r in enumerate(rotations):
        h = K_REF @ r.T @ np.linalg.inv(K)  # frame pixel -> panorama pixel
        f = cv2.warpPerspective(pano, h, (640, 480), flags=cv2.WARP_INVERSE_MAP | cv2.INTER_LINEAR)
        box = np.array([[200 + 12 * t, 150, 300 + 12 * t, 420]], float)
        if person:
            x0, y0, x1, y1 = box[0].astype(int)
            f[y0:y1, x0:x1] = (f[y0:y1, x0:x1] // 2 + 120 + 3 * t % 40).astype(np.uint8)
        frames.append(f)
        boxes.append(box)
    return frames, boxes


def _turns(n=12):
    """A pan of 0.5 degrees a frame with a slow tilt and some roll."""
    return [Rotation.from_euler("yxz", [0.5 * t, 0.2 * t, 0.05 * t], degrees=True).as_matrix() for t in range(n)]


def _angle(a, b):
    return np.degrees(np.arccos(np.clip((np.trace(a @ b.T) - 1) / 2, -1, 1)))


@pytest.mark.parametrize("person", [False, True])
def test_a_panning_camera_s_turn_is_found_with_a_person_masked_out(person):
    truth = _turns()
    frames, boxes = _clip(truth, person)
    found, used = CameraRotations(K)(zip(frames, boxes if person else [None] * len(frames), strict=True))
    assert found.shape == (12, 3, 3) and used[0] == 0 and (used[1:] >= 12).all()
    errors = [_angle(f, t) for f, t in zip(found, truth, strict=True)]
    assert max(errors) < 0.2, errors  # degrees, after 11 steps at 320 px (drift included)
    assert turned_degrees(found) == pytest.approx(turned_degrees(np.stack(truth)), abs=0.2)


def test_a_static_camera_does_not_turn_and_a_blank_frame_is_no_turn():
    frames, boxes = _clip([np.eye(3)] * 4, person=True)
    found, _ = CameraRotations(K)(zip(frames, boxes, strict=True))
    assert turned_degrees(found) < 0.02
    blank = [np.full((480, 640, 3), 128, np.uint8)] * 3
    found, used = CameraRotations(K)((b, None) for b in blank)
    assert np.allclose(found, np.eye(3)) and (used == 0).all()


def test_helpers():
    mask = background_mask((100, 200), np.array([[50, 20, 70, 60]]), grow=0.0)
    assert not mask[30, 60] and mask[10, 10] and mask.sum() == 100 * 200 - 21 * 41
    r = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()
    assert np.allclose(nearest_rotation(3.0 * r), r)


def test_a_frame_that_could_not_be_read_holds_the_last_turn():
    truth = _turns(6)
    frames, _ = _clip(truth)
    cam = CameraRotations(K)
    for n, f in enumerate(frames):
        cam.hold() if n == 3 else cam.add(f, None)
    found, used = cam.result()
    assert found.shape == (6, 3, 3) and used[3] == 0
    assert np.allclose(found[3], found[2]) and _angle(found[4], truth[4]) < 0.2  # frame 4 against frame 2
