"""Synthetic videos with ground truth: held-out mocap clips played by generated people in front of a
static or moving camera, rendered like the image benchmarks (``recon.synth.scene``).

A clip is a ``ClipSpec``: one or two people, each a mocap clip of the pose set from a start frame,
with its own body shape, clothing colours and place on the ground (or another actor's shape and
clothes: a look-alike); a static camera at head height
looks at the scene from a random side; ``aim`` says where: the middle of the people's paths
("middle"), or the end or the start of the first person's path, so that a walker enters or
leaves the frame ("enter", "leave"). ``camera`` moves it: "pan" turns it to follow the first
person, "tilt" nods it up and down while it follows, "handheld" shakes it about where it stands
(a few degrees, a few centimetres), "walk" carries it sideways along the people while it follows.
Frames are 640 x 480 at the pose set's 30 fps, with a fixed light and fresh sensor noise each
frame. A static camera's background is the image generator's; a moving camera's is a street
photograph (``FAR_PHOTOS``, from ``recon.synth.photos``: texture a real street has) far away, seen
through the homography of the camera's turn. Every random choice comes from the clip's seed.
World frame: +Y up, metres, the ground at y = 0; camera: OpenCV, X_cam = R_f @ X_world + t_f in
frame f.

``ClipRenderer(body).render(spec) -> (frames, truth)``; ``write_clip`` stores the frames as an MP4 (what
``recon video`` reads) and the truth as .npz; ``VIDEO_BENCHMARKS`` are the fixed sets.
"""
from __future__ import annotations

import copy
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch
from scipy.spatial.transform import Rotation

from recon import camera, paths
from recon.body.base import BodyModel
from recon.export.media import write_mp4
from recon.poses.mocap import FPS, MocapPoses
from recon.poses.sampler import ShapeSampler
from recon.render.raster import Rasterizer, look_at
from recon.synth.photos import load_photo
from recon.synth.scene import background, vertex_colours

SIZE = (480, 640)  # (H, W)
VIDEO_GENERATOR = 1
CAMERAS = ("static", "pan", "tilt", "handheld", "walk")
CANVAS = 2000  # px wide: a moving camera's background photograph, seen at the clip's focal length
FAR_PHOTOS = ("building.jpg", "leuvenA.jpg", "leuvenB.jpg", "CA_tCA00.jpg", "aero3.jpg")  # streets, large enough
GROUND_PHOTOS = ("aero1.jpg", "graf3.png")  # laid on the ground: texture seen from above
GROUND_HALF, GROUND_CM = 8.0, 1.0  # m: the ground photograph's half width about the aimed point; cm a pixel


@dataclass(frozen=True)
class Actor:
    clip: str  # a clip name of the pose set (``MocapPoses.clips``)
    start: int = 0  # its first frame
    offset: tuple[float, float] = (0.0, 0.0)  # (x, z) metres added to its path, after centring it
    heading: float | None = None  # degrees: the path turned about the vertical to run this way (0: +x, 90: -z)
    look: int | None = None  # a look-alike of actor ``look`` of the clip: its body shape and clothes


@dataclass(frozen=True)
class ClipSpec:
    name: str
    actors: tuple[Actor, ...]
    frames: int
    seed: int
    aim: str = "middle"  # "middle", "enter" or "leave"
    distance: float = 5.0  # camera to the aimed point, metres
    focal: float = 600.0  # pixels
    yaw: float | None = None  # degrees: where the camera stands around the aimed point (0: on +z); None: random
    camera: str = "static"  # or how it moves: ``CAMERAS`` (module doc)
    ground: bool = False  # a photograph laid on the ground around the people (near background: parallax)


# The fixed sets: clips of the held-out subjects of the pose set's val and test splits.
VIDEO_BENCHMARKS: dict[str, list[ClipSpec]] = {
    "synth-video-val": [
        ClipSpec("walk-02_01", (Actor("02_01"),), 80, 11, "middle", 5.5),
        ClipSpec("enter-06_01", (Actor("06_01"),), 90, 12, "enter", 4.5),
        ClipSpec("fight-02_05", (Actor("02_05", 60),), 90, 13, "middle", 4.5),
        ClipSpec("pickup-02_06", (Actor("02_06", 100),), 90, 14, "middle", 4.0),
        ClipSpec("ball-06_02", (Actor("06_02", 20),), 90, 15, "middle", 5.0),
        ClipSpec("two-cross-10_04-02_02", (Actor("10_04", 0, (0.0, 0.6), 0.0), Actor("02_02", 0, (0.0, -0.6), 180.0)),
                 75, 16, "middle", 6.5, yaw=0.0),
    ],
    "synth-video-test": [
        ClipSpec("walk-03_03", (Actor("03_03", 200),), 90, 21, "middle", 6.0),
        ClipSpec("enter-12_01", (Actor("12_01", 20),), 90, 22, "enter", 4.5),
        ClipSpec("leave-09_12", (Actor("09_12", 100),), 90, 23, "leave", 4.5),
        ClipSpec("jump-14_07", (Actor("14_07", 60),), 90, 24, "middle", 4.5),
        ClipSpec("gesture-14_12", (Actor("14_12", 150),), 90, 25, "middle", 4.0),
        ClipSpec("sit-14_27", (Actor("14_27", 120),), 90, 26, "middle", 4.0),
        ClipSpec("climb-14_21", (Actor("14_21", 40),), 90, 27, "middle", 4.5),
        ClipSpec("two-03_01-14_17", (Actor("03_01", 0, (0.0, 0.8), 0.0), Actor("14_17", 100, (1.2, -0.8))), 90, 28,
                 "middle", 6.0, yaw=20.0),
        ClipSpec("two-cross-03_02-12_01", (Actor("03_02", 0, (0.0, 0.6), 0.0), Actor("12_01", 0, (0.0, -0.6), 180.0)),
                 90, 29, "middle", 6.5, yaw=0.0),
    ],
    "synth-video-moving-val": [
        ClipSpec("pan-02_01", (Actor("02_01"),), 80, 31, "middle", 4.0, camera="pan"),
        ClipSpec("handheld-02_05", (Actor("02_05", 60),), 90, 32, "middle", 4.5, camera="handheld"),
        ClipSpec("tilt-06_02", (Actor("06_02", 20),), 90, 33, "middle", 5.0, camera="tilt"),
        ClipSpec("walk-06_01", (Actor("06_01"),), 90, 34, "middle", 4.5, camera="walk"),
    ],
    "synth-video-moving-test": [
        ClipSpec("pan-03_03", (Actor("03_03", 200),), 90, 41, "middle", 4.0, camera="pan"),
        ClipSpec("handheld-14_12", (Actor("14_12", 150),), 90, 42, "middle", 4.0, camera="handheld"),
        ClipSpec("tilt-14_07", (Actor("14_07", 60),), 90, 43, "middle", 4.5, camera="tilt"),
        ClipSpec("walk-09_12", (Actor("09_12", 100),), 90, 44, "middle", 4.5, camera="walk"),
        ClipSpec("pan-two-03_01-14_17", (Actor("03_01", 0, (0.0, 0.8), 0.0), Actor("14_17", 100, (1.2, -0.8))), 90, 45,
                 "middle", 5.0, yaw=20.0, camera="pan"),
    ],
    # A photograph on the ground (parallax) under cameras that travel (walk) and that only turn.
    "synth-video-travel-val": [
        ClipSpec("ground-walk-02_01", (Actor("02_01"),), 80, 71, "middle", 4.5, camera="walk", ground=True),
        ClipSpec("ground-walk-06_01", (Actor("06_01"),), 90, 74, "middle", 4.0, camera="walk", ground=True),
        ClipSpec("ground-pan-06_01", (Actor("06_01"),), 90, 72, "middle", 4.5, camera="pan", ground=True),
        ClipSpec("ground-static-02_05", (Actor("02_05", 60),), 60, 73, "middle", 4.5, ground=True),
        ClipSpec("ground-handheld-02_06", (Actor("02_06", 100),), 90, 75, "middle", 4.0, camera="handheld",
                 ground=True),
    ],
    "synth-video-travel-test": [
        ClipSpec("ground-walk-12_01", (Actor("12_01", 20),), 90, 81, "middle", 4.5, camera="walk", ground=True),
        ClipSpec("ground-walk-14_12", (Actor("14_12", 150),), 90, 82, "middle", 4.0, camera="walk", ground=True),
        ClipSpec("ground-handheld-03_03", (Actor("03_03", 200),), 90, 83, "middle", 4.5, camera="handheld",
                 ground=True),
        ClipSpec("ground-tilt-14_07", (Actor("14_07", 60),), 90, 84, "middle", 4.5, camera="tilt", ground=True),
    ],
    # Look-alikes (one body shape, one outfit) where one passes behind the other: who is who must
    # come from the motion through the gap, not from the looks.
    "synth-video-occlusion-val": [
        ClipSpec("behind-10_04-02_10", (Actor("02_10", 100, (0.0, 0.8)), Actor("10_04", 0, (0.0, -0.6), 0.0, 0)),
                 90, 51, "middle", 6.5, yaw=0.0),
        ClipSpec("cross-02_01-06_01", (Actor("02_01", 0, (0.0, 0.6), 0.0), Actor("06_01", 10, (0.0, -0.6), 180.0, 0)),
                 80, 52, "middle", 6.5, yaw=0.0),
    ],
    "synth-video-occlusion-test": [
        ClipSpec("behind-12_01-14_12", (Actor("14_12", 150, (0.0, 0.8)), Actor("12_01", 20, (0.0, -0.6), 0.0, 0)),
                 90, 61, "middle", 6.5, yaw=0.0),
        ClipSpec("cross-03_02-12_01", (Actor("03_02", 0, (0.0, 0.6), 0.0), Actor("12_01", 0, (0.0, -0.6), 180.0, 0)),
                 90, 62, "middle", 6.5, yaw=0.0),
        ClipSpec("overtake-09_12-12_01",
                 (Actor("09_12", 100, (0.3, 0.6), 0.0), Actor("12_01", 10, (-0.3, -0.6), 0.0, 0)), 90, 63, "middle",
                 6.5, yaw=10.0),
    ],
}


@dataclass
class ClipTruth:
    """Ground truth of one clip, person p at frame f. Camera frame: OpenCV, metres."""

    K: np.ndarray  # (3, 3)
    R: np.ndarray  # (F, 3, 3) world -> camera of each frame
    t: np.ndarray  # (F, 3)
    joints: np.ndarray  # (P, F, 24, 3) camera frame
    points: np.ndarray  # (P, F, 42, 3) J+ in the camera frame
    vertices: np.ndarray  # (P, F, V, 3) float16, camera frame minus the pelvis
    joints_world: np.ndarray  # (P, F, 24, 3)
    pose: np.ndarray  # (P, F, 24, 3) axis-angle, root in the world frame
    shape: np.ndarray  # (P, S)
    visible: np.ndarray  # (P, F) bool: in front of the camera with at least 12 J+ inside the frame
    fps: float = FPS
    meta: dict = field(default_factory=dict)

    def save(self, path: Path) -> None:
        arrays = {k: v for k, v in asdict(self).items() if k != "meta"}
        arrays["meta"] = np.array(json.dumps(self.meta))
        paths.atomic_write(path, lambda tmp: np.savez_compressed(open(tmp, "wb"), **arrays))

    @classmethod
    def load(cls, path: Path) -> ClipTruth:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
        d["meta"] = json.loads(str(d["meta"]))
        d["fps"] = float(d["fps"])
        if d["R"].ndim == 2:  # stored before cameras moved: one camera for every frame
            frames = d["joints"].shape[1]
            d["R"], d["t"] = np.repeat(d["R"][None], frames, 0), np.repeat(d["t"][None], frames, 0)
        return cls(**d)


class ClipRenderer:
    """Renders ``ClipSpec`` clips with one body model and rasteriser (reuse it across clips)."""

    def __init__(self, body: BodyModel, poses: MocapPoses | None = None):
        self.body = copy.deepcopy(body).double()  # float64 geometry, as the image generator
        self.poses = poses or MocapPoses.load()
        self.by_name = {c["name"]: i for i, c in enumerate(self.poses.clips)}
        self.faces = body.faces.numpy()
        self.parts = body.weights.argmax(1).numpy()
        self.raster = Rasterizer(SIZE[1], SIZE[0])

    def _motion(self, actor: Actor, frames: int) -> tuple[np.ndarray, np.ndarray]:
        """(F, 24, 3) axis-angle and (F, 3) pelvis path of an actor: its clip from ``start``, held on
        its last frame past the clip's end, centred on the ground at the origin plus ``offset``."""
        if actor.clip not in self.by_name:
            raise KeyError(f"no clip {actor.clip!r} in the pose set")
        sel = np.flatnonzero(self.poses.clip == self.by_name[actor.clip])
        idx = sel[np.minimum(actor.start + np.arange(frames), len(sel) - 1)]
        rot, tr = self.poses.rotvec[idx].astype(np.float64), self.poses.transl[idx].astype(np.float64)
        tr[:, [0, 2]] -= tr[:, [0, 2]].mean(0)
        if actor.heading is not None:
            way = tr[-1] - tr[0]
            turn = Rotation.from_euler("y", np.radians(actor.heading) + np.arctan2(way[2], way[0]))
            rot[:, 0] = (turn * Rotation.from_rotvec(rot[:, 0])).as_rotvec()
            tr = turn.apply(tr)
        tr[:, [0, 2]] += np.asarray(actor.offset)
        return rot, tr

    def render(self, spec: ClipSpec) -> tuple[list[np.ndarray], ClipTruth]:
        rng = np.random.default_rng([VIDEO_GENERATOR, spec.seed])
        torch.manual_seed(spec.seed)
        shapes = ShapeSampler(self.body, seed=spec.seed).sample(len(spec.actors)).double()
        for p, actor in enumerate(spec.actors):
            if actor.look is not None:
                shapes[p] = shapes[actor.look]
        joints, points, verts, colours = [], [], [], []
        poses = []
        for p, actor in enumerate(spec.actors):
            rot, tr = self._motion(actor, spec.frames)
            with torch.no_grad():
                out = self.body(torch.from_numpy(rot), shapes[p:p + 1].expand(spec.frames, -1),
                                transl=torch.from_numpy(tr))
            v = out.vertices.numpy()
            lift = -v[..., 1].min()  # the lowest point over the clip on the ground
            joints.append(out.joints.numpy() + [0, lift, 0])
            points.append(out.points.numpy() + [0, lift, 0])
            verts.append(v + [0, lift, 0])
            own = vertex_colours(rng, out.rest_vertices[0].numpy(), self.parts)  # drawn always: the same clip per seed
            colours.append(own if actor.look is None else colours[actor.look])
            poses.append(rot)
        path = joints[0][:, 0]
        target = {"middle": np.concatenate([j[:, 0] for j in joints]).mean(0), "enter": path[-1],
                  "leave": path[0]}[spec.aim].copy()
        target[1] = 1.0
        yaw = rng.uniform(0, 2 * np.pi) if spec.yaw is None else np.radians(spec.yaw)
        eye = target + spec.distance * np.array([np.sin(yaw), 0.0, np.cos(yaw)])
        eye[1] = rng.uniform(1.2, 1.7)
        k = np.array([[spec.focal, 0, SIZE[1] / 2], [0, spec.focal, SIZE[0] / 2], [0, 0, 1.0]])
        bg = background(rng, SIZE[1]) if spec.camera == "static" else far_photo(rng)
        light = rng.normal(0, 1, 3) * [1, 1, 0.3] + [0, 0, 1.0]
        ambient = rng.uniform(0.35, 0.6)
        noise = rng.uniform(1, 5)
        r, t = camera_path(spec, eye, target, path, rng)
        ground = ground_photo(rng) if spec.ground else None  # drawn last: the clips without one unchanged
        to_cam = lambda x: np.einsum("fij,f...j->f...i", r, x) + t[:, None]  # noqa: E731
        faces = np.concatenate([self.faces + p * len(colours[0]) for p in range(len(spec.actors))])
        cols = np.concatenate(colours)
        frames, n_mid = [], spec.frames // 2  # the background photo faces the middle frame's camera
        for f in range(spec.frames):
            vc = np.concatenate([v[f] @ r[f].T + t[f] for v in verts])
            rgb, labels, _ = self.raster.render(vc, faces, k, cols, None, light_dir=-light, ambient=ambient)
            img = bg[:SIZE[0]].copy() if spec.camera == "static" else far_background(bg, k, r[n_mid], r[f])
            if spec.ground:
                laid_on_ground(img, ground, target, k, r[f], t[f])
            img[labels >= 0] = rgb[labels >= 0]
            grain = rng.standard_normal(img.shape, dtype=np.float32) * np.float32(noise)
            frames.append(np.clip(img.astype(np.float32) + grain, 0, 255).astype(np.uint8))
        pts_cam = np.stack([to_cam(p) for p in points])
        uv = camera.project(pts_cam.reshape(-1, 3), k).reshape(pts_cam.shape[:-1] + (2,))
        inside = camera.inside_image(uv.reshape(-1, 2), SIZE).reshape(uv.shape[:-1]) & (pts_cam[..., 2] > 0.1)
        jc = np.stack([to_cam(j) for j in joints])
        vc = np.stack([to_cam(v) for v in verts]) - jc[:, :, :1]
        world_pose = np.stack(poses)
        truth = ClipTruth(K=k, R=r, t=t, joints=jc, points=pts_cam, vertices=vc.astype(np.float16),
                          joints_world=np.stack(joints), pose=world_pose.astype(np.float32),
                          shape=shapes.numpy().astype(np.float32), visible=inside.sum(-1) >= 12,
                          meta={"spec": asdict(spec), "generator": VIDEO_GENERATOR})
        return frames, truth


def camera_path(spec: ClipSpec, eye: np.ndarray, target: np.ndarray, path: np.ndarray,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3, 3), (F, 3): each frame's world -> camera (module doc); ``path``: the first person's
    pelvis (F, 3), which a moving camera follows (held steady: a half-second moving average)."""
    n = spec.frames
    if spec.camera not in CAMERAS:
        raise ValueError(f"camera {spec.camera!r}: one of {CAMERAS}")
    if spec.camera == "static":
        r, t = look_at(eye, target)
        return np.repeat(r[None], n, 0), np.repeat(t[None], n, 0)
    pad = np.pad(path, ((7, 7), (0, 0)), mode="edge")
    follow = np.stack([pad[f:f + 15].mean(0) for f in range(n)]) * [1, 0, 1] + [0, target[1], 0]
    s = np.linspace(0.0, 1.0, n)
    eyes, targets, shake = np.repeat(eye[None], n, 0), follow, np.zeros((n, 3))
    if spec.camera == "tilt":
        nod = np.linalg.norm(eye - target) * np.tan(np.radians(6.0)) * np.sin(2 * np.pi * s)  # +-6 degrees
        targets = follow + np.outer(nod, [0.0, 1.0, 0.0])
    elif spec.camera == "handheld":  # about where it stands: slow sway and a faster tremor
        targets = np.repeat(target[None], n, 0)
        time = np.arange(n) / FPS
        for hz, degrees in ((0.4, 2.0), (1.3, 0.8), (4.0, 0.25)):
            shake += np.radians(degrees) * np.sin(2 * np.pi * hz * time[:, None] + rng.uniform(0, 2 * np.pi, 3))
        eyes = eye + 0.02 * np.sin(2 * np.pi * 0.7 * time[:, None] + rng.uniform(0, 2 * np.pi, 3))
    elif spec.camera == "walk":  # a tracking shot: sideways, 1.5 m over the clip
        side = np.cross([0.0, 1.0, 0.0], target - eye)
        eyes = eye + np.outer(s - 0.5, 1.5 * side / np.linalg.norm(side))
    rs, ts = zip(*(look_at(e, g) for e, g in zip(eyes, targets, strict=True)), strict=True)
    turn = Rotation.from_rotvec(shake).as_matrix()  # about the camera's own centre
    r = turn @ np.stack(rs)
    return r, np.einsum("fij,fj->fi", turn, np.stack(ts))


def far_photo(rng: np.random.Generator) -> np.ndarray:
    """A moving camera's background: one of ``FAR_PHOTOS``, ``CANVAS`` pixels wide, maybe mirrored."""
    im = load_photo(FAR_PHOTOS[rng.integers(len(FAR_PHOTOS))])
    im = cv2.resize(im, (CANVAS, round(CANVAS * im.shape[0] / im.shape[1])), interpolation=cv2.INTER_CUBIC)
    return np.ascontiguousarray(im[:, ::-1]) if rng.random() < 0.5 else im


def far_background(canvas: np.ndarray, k: np.ndarray, r_canvas: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The photograph ``canvas`` (seen at ``k``'s focal length by a camera turned as ``r_canvas``)
    far away, as the camera turned ``r`` sees it: the homography of the turn."""
    kc = np.array([[k[0, 0], 0, canvas.shape[1] / 2], [0, k[1, 1], canvas.shape[0] / 2], [0, 0, 1.0]])
    m = kc @ r_canvas @ r.T @ np.linalg.inv(k)  # a frame's pixel -> the canvas's
    return cv2.warpPerspective(canvas, m, (SIZE[1], SIZE[0]), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                               borderMode=cv2.BORDER_REFLECT)


def ground_photo(rng: np.random.Generator) -> np.ndarray:
    """One of ``GROUND_PHOTOS`` as a square ``2 * GROUND_HALF`` metres wide at ``GROUND_CM`` cm a pixel."""
    side = round(2 * GROUND_HALF * 100 / GROUND_CM)
    im = load_photo(GROUND_PHOTOS[rng.integers(len(GROUND_PHOTOS))])
    return cv2.resize(im, (side, side), interpolation=cv2.INTER_CUBIC)


def laid_on_ground(img: np.ndarray, photo: np.ndarray, centre: np.ndarray, k: np.ndarray, r: np.ndarray,
                   t: np.ndarray) -> None:
    """Draw ``photo`` lying on the ground (y = 0) about ``centre``'s x, z into ``img`` (in place) as
    the camera (r, t) sees it: each pixel's ray to where it meets the ground."""
    h, w = img.shape[:2]
    u, v = np.meshgrid(np.arange(w, dtype=np.float64) + 0.5, np.arange(h, dtype=np.float64) + 0.5)
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(k).T @ r  # world directions (R^T K^-1 x)
    eye = -r.T @ t
    down = rays[..., 1] < -1e-6
    dist = np.where(down, -eye[1] / np.where(down, rays[..., 1], -1.0), 0.0)
    x = eye[0] + dist * rays[..., 0] - centre[0] + GROUND_HALF
    z = eye[2] + dist * rays[..., 2] - centre[2] + GROUND_HALF
    px = 100.0 / GROUND_CM
    hit = down & (x > 0) & (x < 2 * GROUND_HALF) & (z > 0) & (z < 2 * GROUND_HALF)
    seen = cv2.remap(photo, (x * px).astype(np.float32), (z * px).astype(np.float32), cv2.INTER_LINEAR)
    img[hit] = seen[hit]


def write_clip(frames: list[np.ndarray], path: Path, fps: float = FPS) -> Path:
    """The frames as an MP4 (OpenCV's MPEG-4 part 2 at high quality), atomically."""
    return write_mp4(path, frames, fps, frames[0].shape[:2], quality=100)
