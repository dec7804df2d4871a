"""Following people across frames, the track optimisation and its pieces, the temporal metrics."""
import numpy as np
import pytest
import roma
import torch

from recon import camera, metrics
from recon.video.ground import FOOT_POINTS, ground_plane, to_world
from recon.video.smooth import SmoothConfig, TrackInput, fill_gaps, planted, smooth_track, windows
from recon.video.track import Detection, TrackerConfig, appearance, appearance_distance, track

K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])


def _person(x: float, y: float = 100.0, size: float = 200.0) -> tuple[np.ndarray, np.ndarray]:
    box = np.array([x, y, x + size / 2, y + size])
    rng = np.random.default_rng(int(x))
    pts = box[:2] + rng.uniform(0, 1, (42, 2)) * [size / 2, size]
    return box, pts


def _frames(paths: list[list[float | None]], colours=None) -> list[list[Detection]]:
    """Detections of people at x positions per frame (None: not seen), in the order given."""
    out = []
    for f, xs in enumerate(paths):
        dets = []
        for p, x in enumerate(xs):
            if x is None:
                continue
            box, pts = _person(x)
            hist = None if colours is None else colours[p]
            dets.append(Detection(f, box, pts, hist, len(dets)))
        out.append(dets)
    return out


def _ids(tracks, frames: int) -> list[dict[int, int]]:
    """Per frame {detection index: track id}."""
    per = [dict() for _ in range(frames)]
    for t in tracks:
        for d in t.detections:
            per[d.frame][d.index] = t.id
    return per


def test_two_people_walking_past_each_other_keep_their_ids():
    # A walks right, B walks left; they cross at frame 10, the detector lists them in either order
    frames = []
    for f in range(21):
        a, b = 100 + 20 * f, 500 - 20 * f
        frames.append([a, b] if f % 2 else [b, a])
    tracks = track(_frames(frames), TrackerConfig(min_frames=3))
    assert len(tracks) == 2
    first_x = {t.id: t.detections[0].box[0] for t in tracks}
    for t in tracks:  # each track's boxes move one way only: no identity switch at the crossing
        xs = [d.box[0] for d in t.detections]
        assert len(xs) == 21 and (np.all(np.diff(xs) > 0) or np.all(np.diff(xs) < 0))
    assert sorted(first_x.values()) == [100.0, 500.0]


def test_a_gap_is_bridged_and_a_flicker_is_dropped():
    frames = [[100 + 5 * f] for f in range(30)]
    for f in range(10, 16):
        frames[f] = []  # missed for six frames
    frames[20] = frames[20] + [600.0]  # one frame of something far away
    tracks = track(_frames(frames), TrackerConfig(max_gap=10, min_frames=3))
    assert len(tracks) == 1 and len(tracks[0].detections) == 24
    assert tracks[0].frames[0] == 0 and tracks[0].frames[-1] == 29


def test_a_person_back_after_a_long_absence_gets_their_id_by_appearance():
    rng = np.random.default_rng(0)
    red = np.zeros((64, 64, 3), np.uint8)
    red[..., 0] = 200
    blue = np.zeros((64, 64, 3), np.uint8)
    blue[..., 2] = 200
    blue[..., 1] = rng.integers(0, 60, (64, 64))
    h_red, h_blue = appearance(red, (0, 0, 64, 64)), appearance(blue, (0, 0, 64, 64))
    assert appearance_distance(h_red, h_red) < 0.05 and appearance_distance(h_red, h_blue) > 0.9
    # red at x=100 for 10 frames, gone 40 frames, back at x=400; blue at x=250 all along
    frames = [[100.0 if f < 10 else (400.0 if f >= 50 else None), 250.0] for f in range(60)]
    tracks = track(_frames(frames, colours=[h_red, h_blue]), TrackerConfig(max_gap=15, min_frames=3))
    assert len(tracks) == 2
    red_track = next(t for t in tracks if t.detections[0].box[0] == 100.0)
    assert red_track.frames[:10] == list(range(10)) and red_track.frames[10:] == list(range(50, 60))
    # without appearance the returning person is somebody new
    tracks = track(_frames(frames), TrackerConfig(max_gap=15, min_frames=3))
    assert len(tracks) == 3


def test_max_people_keeps_the_longest_tracks_numbered_by_first_appearance():
    frames = [[100.0, 300.0 if f >= 5 else None, 500.0 if f < 8 else None] for f in range(20)]
    tracks = track(_frames(frames), TrackerConfig(min_frames=3, max_people=2))
    assert [t.id for t in tracks] == [0, 1]
    assert [len(t.detections) for t in tracks] == [20, 15]


def test_fill_gaps_slerps_rotations_and_interpolates_positions():
    rot = np.tile(np.eye(3), (5, 24, 1, 1))
    rot[4, 3] = roma.rotvec_to_rotmat(torch.tensor([0.0, 0.0, 1.2], dtype=torch.float64)).numpy()
    tr = np.zeros((5, 3))
    tr[4] = [4.0, 0, 0]
    seen = np.array([True, False, False, False, True])
    r, t = fill_gaps(seen, rot, tr)
    angles = roma.rotmat_to_rotvec(torch.tensor(r[:, 3]))[:, 2].numpy()
    assert angles == pytest.approx([0, 0.3, 0.6, 0.9, 1.2], abs=1e-9)
    assert t[:, 0] == pytest.approx([0, 1, 2, 3, 4])
    first_unseen = np.array([False, True, True, True, True])
    r, t = fill_gaps(first_unseen, rot, tr)
    assert t[0, 0] == pytest.approx(0.0) and np.allclose(r[0], rot[1])  # held before the first seen frame


def test_ground_plane_finds_a_tilted_floor_and_a_line_of_steps_keeps_the_up_prior():
    rng = np.random.default_rng(1)
    n_true = np.array([0.0, -np.cos(0.2), np.sin(0.2)])  # camera frame: y down, the floor tilted by 0.2 rad
    xy = rng.uniform(-1, 1, (50, 2))
    a = np.cross(n_true, [1.0, 0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n_true, a)
    pts = xy[:, :1] * a + xy[:, 1:] * b + 1.5 * n_true + [0, 0, 4]
    n, d = ground_plane(pts, up=np.array([0.0, -1.0, 0.0]), sole=0.05)
    # the up prior pulls a little (11.5 degrees of tilt; a 2 m square of steps)
    assert np.degrees(np.arccos(n @ n_true)) < 2.5
    assert d == pytest.approx(np.median(pts @ n) - 0.05)
    line = np.array([[0.0, 1.6, 3 + s] for s in np.linspace(0, 2, 10)])  # footsteps along one line
    n, _ = ground_plane(line, up=np.array([0.0, -1.0, 0.0]), sole=0.05)
    assert n == pytest.approx([0, -1, 0], abs=1e-6)
    r, o = to_world((n_true, 1.0), np.array([0.2, 0.4, 4.0]))
    assert np.allclose(r @ r.T, np.eye(3)) and np.linalg.det(r) == pytest.approx(1.0)
    assert r[1] == pytest.approx(n_true) and o @ n_true == pytest.approx(1.0)
    assert r[2, 2] < 0  # Z towards the camera


def _walk(body, mocap, frames=24):
    """A true walk seen by K: camera-frame rotations, translations, J+ and 2D J+."""
    clip = next(i for i, c in enumerate(mocap.clips) if c["name"] == "12_01")  # a walk on flat ground
    sel = np.flatnonzero(mocap.clip == clip)[20:20 + frames]
    rot = roma.rotvec_to_rotmat(torch.tensor(mocap.rotvec[sel], dtype=torch.float64)).numpy()
    rot[:, 0] = camera.HALF_TURN_X @ rot[:, 0]
    tr = (mocap.transl[sel] - mocap.transl[sel].mean(0)) @ camera.HALF_TURN_X.T + [0, 0, 4.0]
    shape = body.mean_shape.numpy().astype(np.float64)
    with torch.no_grad():
        o = body(torch.tensor(rot, dtype=torch.float32), torch.tensor(shape[None], dtype=torch.float32),
                 transl=torch.tensor(tr, dtype=torch.float32))
    pts = o.points.numpy().astype(np.float64)
    return rot, tr, shape, pts, camera.project(pts, K)


def test_the_track_optimisation_removes_jitter_and_keeps_the_pose(body, mocap):
    rot, tr, shape, pts, uv = _walk(body, mocap)
    rng = np.random.default_rng(0)
    t = len(rot)
    noise = roma.rotvec_to_rotmat(torch.tensor(rng.normal(0, 0.08, (t, 24, 3)))).numpy()
    seen = np.ones(t, bool)
    seen[10:13] = False  # a gap
    boxes = np.concatenate([uv.min(1), uv.max(1)], 1)
    inp = TrackInput(seen, uv + rng.normal(0, 2.0, uv.shape), pts - pts[:, :1] + rng.normal(0, 0.02, pts.shape),
                     boxes, rot @ noise, tr + rng.normal(0, 0.05, tr.shape), shape, K, (480, 640))
    raw = smooth_track(body, inp, SmoothConfig(steps=0))
    smooth = smooth_track(body, inp, SmoothConfig())
    truth = torch.tensor(pts[:, :24])
    err = {k: float(metrics.mpjpe(torch.tensor(m.joints), truth) * 1000) for k, m in (("raw", raw), ("smooth", smooth))}
    acc = {k: float(metrics.acceleration_error(torch.tensor(m.joints), truth) * 1000)
           for k, m in (("raw", raw), ("smooth", smooth))}
    assert acc["smooth"] < acc["raw"] / 3, acc
    assert err["smooth"] < err["raw"], err
    assert smooth.joints.shape == (t, 24, 3) and smooth.rotmats.shape == (t, 24, 3, 3)
    n, _ = smooth.ground
    assert n[1] < -0.97  # the floor's up is the camera's -y


def test_planted_feet_are_the_still_low_ones():
    t = 12
    uv = np.zeros((t, 42, 2))
    uv[..., 0] = 300.0
    uv[..., 1] = np.linspace(100, 300, 42)
    for s, side in enumerate(("left", "right")):
        for j in FOOT_POINTS[side]:
            uv[:, j, 1] = 400.0
            uv[:, j, 0] = 280 + 40 * s + (np.arange(t) * 15.0 if side == "right" else 0.0)  # the right foot swings
    boxes = np.tile([250.0, 100, 350, 400], (t, 1))
    inp = TrackInput(np.ones(t, bool), uv, None, boxes, None, None, None, K, (480, 640))
    p = planted(inp, SmoothConfig())
    assert p[1:-1, 0].all() and not p[:, 1].any()
    assert not p[0].any() and not p[-1].any()  # no speed at the ends


def test_temporal_metrics():
    t = torch.arange(10, dtype=torch.float64)
    x = torch.zeros(10, 3, 3, dtype=torch.float64)
    x[:, 1, 0] = 0.5 * t ** 2  # point 1 accelerates by 1 a frame^2 along x
    assert metrics.acceleration(x)[:, 1, 0] == pytest.approx(torch.ones(8))
    assert float(metrics.acceleration_error(x, torch.zeros_like(x))) == pytest.approx(1 / 3)
    assert float(metrics.acceleration_error(x, x)) == 0.0
    assert float(metrics.jitter(x)) == pytest.approx(0.0, abs=1e-12)
    y = x.clone()
    y[::2, 2, 1] += 1.0  # alternating: jerk 4 on point 2
    assert float(metrics.jitter(y)) == pytest.approx(4 / 3)
    feet = torch.zeros(5, 2, 3, dtype=torch.float64)
    feet[:, 0, 0] = torch.arange(5) * 0.1  # left foot slides 0.1 a frame, right stays
    plant = torch.tensor([[True, True]] * 5)
    assert float(metrics.foot_skating(feet, plant)) == pytest.approx(0.05)
    assert torch.isnan(metrics.foot_skating(feet, torch.zeros(5, 2, dtype=torch.bool)))
    with pytest.raises(ValueError):
        metrics.acceleration(x[:2])


def test_depth_acceleration_weighs_the_line_of_sight_only(body, mocap):
    """``depth_acceleration`` equal to ``acceleration`` is the one acceleration term; a far larger
    one smooths the depth more than motion across the image."""
    rot, tr, shape, pts, uv = _walk(body, mocap, frames=12)
    rng = np.random.default_rng(3)
    t = len(rot)
    boxes = np.concatenate([uv.min(1), uv.max(1)], 1)
    tr_noisy = tr + rng.normal(0, 0.05, tr.shape) * [0.2, 0.2, 1.0]  # depth is what the frames fix least
    inp = TrackInput(np.ones(t, bool), uv + rng.normal(0, 1.0, uv.shape), pts - pts[:, :1], boxes, rot, tr_noisy,
                     shape, K, (480, 640))
    same = smooth_track(body, inp, SmoothConfig(steps=15, depth_acceleration=SmoothConfig.acceleration))
    one = smooth_track(body, inp, SmoothConfig(steps=15))
    assert np.abs(same.joints - one.joints).max() < 1e-4
    stiff = smooth_track(body, inp, SmoothConfig(steps=15, depth_acceleration=1e4))
    depth_jerk = lambda m: np.abs(np.diff(m.joints[:, :, 2] - m.joints[:, :1, 2], 2, axis=0)).mean()  # noqa: E731
    assert depth_jerk(stiff) < depth_jerk(one)


def test_a_turning_camera_s_frames_give_the_motion_in_the_first_frame_s_camera(body, mocap):
    """Frames seen by a camera turning 15 degrees: with the turns the track's estimates are taken
    into the first frame's camera (exactly, without steps), and the optimisation stays there."""
    rot, tr, shape, pts, _ = _walk(body, mocap)
    t = len(rot)
    turns = roma.rotvec_to_rotmat(torch.tensor(np.outer(np.linspace(0, np.radians(15), t), [0.2, 1.0, 0.1]))).numpy()
    seen_pts = np.einsum("tij,tnj->tni", turns, pts)  # each frame's camera
    uv = camera.project(seen_pts, K)
    rot_seen = rot.copy()
    rot_seen[:, 0] = turns @ rot[:, 0]
    boxes = np.concatenate([uv.min(1), uv.max(1)], 1)
    inp = TrackInput(np.ones(t, bool), uv, seen_pts - seen_pts[:, :1], boxes, rot_seen,
                     np.einsum("tij,tj->ti", turns, tr), shape, K, (480, 640), turns)
    exact = smooth_track(body, inp, SmoothConfig(steps=0))
    assert np.abs(exact.points - pts).max() < 1e-4 and np.abs(exact.translation - tr).max() < 1e-6
    smooth = smooth_track(body, inp, SmoothConfig(steps=20))
    assert float(metrics.mpjpe(torch.tensor(smooth.joints), torch.tensor(pts[:, :24]))) < 0.02
    still = smooth_track(body, TrackInput(*[getattr(inp, f) for f in ("seen", "points2d", "points3d", "boxes",
                                                                        "rotmats", "translation", "shape", "K",
                                                                        "image_shape")]), SmoothConfig(steps=0))
    assert np.abs(still.points - seen_pts).max() < 1e-4  # without the turns: each frame's own camera


def test_windows_cover_the_track_and_overlap_by_the_given_frames():
    assert windows(50, 60, 10) == [(0, 50)]
    w = windows(250, 100, 20)
    assert w[0][0] == 0 and w[-1][1] == 250 and all(b - a <= 100 for a, b in w)
    assert all(b1 - a2 == 20 for (_, b1), (a2, _) in zip(w[:-1], w[1:]))


def test_a_long_track_in_windows_is_as_good_as_in_one(body, mocap):
    rot, tr, shape, pts, uv = _walk(body, mocap, frames=120)
    rng = np.random.default_rng(1)
    t = len(rot)
    noise = roma.rotvec_to_rotmat(torch.tensor(rng.normal(0, 0.08, (t, 24, 3)))).numpy()
    boxes = np.concatenate([uv.min(1), uv.max(1)], 1)
    inp = TrackInput(np.ones(t, bool), uv + rng.normal(0, 2.0, uv.shape),
                     pts - pts[:, :1] + rng.normal(0, 0.02, pts.shape), boxes, rot @ noise,
                     tr + rng.normal(0, 0.05, tr.shape), shape, K, (480, 640))
    one = smooth_track(body, inp, SmoothConfig(steps=120, window=t))
    parts = smooth_track(body, inp, SmoothConfig(steps=120, window=60, overlap=30))
    truth = torch.tensor(pts[:, :24])
    err = {k: np.linalg.norm(m.joints - pts[:, :24], axis=-1).mean() for k, m in (("one", one), ("parts", parts))}
    acc = {k: float(metrics.acceleration_error(torch.tensor(m.joints), truth)) for k, m in (("one", one),
                                                                                            ("parts", parts))}
    # the optimisation stops early (its iterations, not its optimum, are what was tuned), so the two
    # answers are not the same, but as close to the truth and as smooth, the seams included
    assert err["parts"] < 1.1 * err["one"] + 0.002, err
    assert acc["parts"] < 1.2 * acc["one"], acc
    seam = slice(60 - 30 - 2, 60 + 2)  # the overlap of the first two windows
    seam_acc = float(metrics.acceleration_error(torch.tensor(parts.joints[seam]), truth[seam]))
    assert seam_acc < 2 * acc["one"], (seam_acc, acc)
    assert np.linalg.norm(parts.points - one.points, axis=-1).mean() < 0.02
    with pytest.raises(ValueError, match="overlap"):
        smooth_track(body, inp, SmoothConfig(window=30, overlap=30))


def test_feet_planted_by_the_image_the_motion_prior_or_either(body, mocap):
    rot, tr, shape, pts, uv = _walk(body, mocap)
    t = len(rot)
    boxes = np.concatenate([uv.min(1), uv.max(1)], 1)
    inp = TrackInput(np.ones(t, bool), uv, pts - pts[:, :1], boxes, rot, tr, shape, K, (480, 640))
    plant = {c: smooth_track(body, inp, SmoothConfig(steps=0, contact_from=c)).planted
             for c in ("image", "prior", "either")}
    assert (plant["either"] == (plant["image"] | plant["prior"])).all()
    assert plant["prior"].any() and not plant["prior"].all()  # a walk: each foot planted part of the time
    with pytest.raises(ValueError, match="contact_from"):
        smooth_track(body, inp, SmoothConfig(steps=0, contact_from="feet"))


def test_planted_feet_are_low_and_still_in_the_world():
    """+Y up: a foot resting on the floor is planted; one lifted or sliding is not, and the first
    frame takes the second's speed."""
    t = torch.arange(6, dtype=torch.float64)
    feet = torch.zeros(2, 6, 2, 3, dtype=torch.float64)  # 2 people, 6 frames, 2 feet
    feet[0, :, 1, 1] = torch.tensor([0.0, 0.0, 0.2, 0.2, 0.0, 0.0])  # the right foot lifted at frames 2-3
    feet[1, :, 0, 0] = 0.05 * t  # the left foot slides 5 cm a frame
    p = metrics.planted_feet(feet)
    assert p.shape == (2, 6, 2)
    assert p[0, :, 0].all() and p[1, :, 1].all()
    assert p[0, :, 1].tolist() == [True, True, False, False, False, True]
    assert not p[1, :, 0].any()


def _lookalikes(hidden_width: float = 70.0, frames: int = 60) -> list[list[Detection]]:
    """Two people alike (no colours to tell them apart): one stands at x=300, 6 m away; the other
    walks right 8 px a frame, 8 m away (a smaller box), and is not seen while it passes behind."""
    out = []
    for f in range(frames):
        people = [(300.0, 6.0)]
        x = 100.0 + 8.0 * f
        if abs(x - 300.0) > hidden_width:
            people.append((x, 8.0))
        dets = []
        for x, depth in (people if f % 2 else people[::-1]):  # listed in either order
            size = 1200.0 / depth
            box, pts = _person(x, 260.0 - size, size)
            dets.append(Detection(f, box, pts, None, len(dets), depth))
        out.append(dets)
    return out


def test_a_look_alike_passing_behind_another_keeps_its_id():
    frames = _lookalikes()
    tracks = track(frames, TrackerConfig(min_frames=3))
    assert len(tracks) == 2
    stander = next(t for t in tracks if all(abs(d.box[0] - 300.0) < 1 for d in t.detections[:3]))
    walker = next(t for t in tracks if t is not stander)
    assert all(abs(d.box[0] - 300.0) < 1 for d in stander.detections)  # never took the walker's box
    assert len(stander.detections) == 60
    xs = [d.box[0] for d in walker.detections]
    assert np.all(np.diff(xs) > 0) and xs[0] == 100.0 and xs[-1] == 100.0 + 8.0 * 59
    gaps = np.diff(walker.frames)
    assert gaps.max() > 10  # it came back after the gap, under its own id


def test_motion_through_the_gap_is_what_keeps_the_look_alikes_apart():
    # the 0.29 tracker (box overlap and keypoints only) swaps them: the walker's track takes the
    # standing one's box while the walker is hidden, and the standing one's track the walker's return
    tracks = track(_lookalikes(), TrackerConfig(min_frames=3, motion=False))
    swapped = [t for t in tracks if any(d.box[0] == 300.0 for d in t.detections)
               and any(d.box[0] != 300.0 for d in t.detections)]
    assert len(swapped) == 2


def test_the_predicted_box_follows_a_straight_walk_through_a_gap():
    t = track([[d for d in fr if d.depth == 8.0] for fr in _lookalikes(frames=20)],
              TrackerConfig(min_frames=3))[0]
    centre, height, depth = t.predicted(40)
    last = t.last
    assert centre[0] == pytest.approx((last.box[0] + last.box[2]) / 2 + 8.0 * (40 - last.frame), abs=1e-6)
    assert height == pytest.approx(150.0) and depth == pytest.approx(8.0)
