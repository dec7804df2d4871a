"""What ``recon video`` writes for a track, and the overlay video of the clip.

Per track (``write_track``): ``motion.bvh`` (the motion on the track's own skeleton, centimetres),
``animated.glb`` (skinned body with the track's shape, dressed with an outfit when asked; NCS
dynamics where the outfit has them), ``motion.json`` and ``person.jpg`` (``write_portrait``: who
the track is, cut from the clip), all in the clip's world frame, the same for every track (+Y up
from the estimated ground, feet on y = 0, Z towards the camera; ``recon.video.ground``).
``OverlayFrames`` draws the frames of ``overlay.mp4``: every track's body over the frame, side
by side with a 3D view of the bodies on the clip's ground. A body the
track bridges (its person not found in that frame) is drawn fainter, and not at all in a gap
longer than ``MAX_DRAWN_GAP`` seconds: the files keep the whole track, the picture does not
pretend to have seen it.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import roma
import torch

from recon.body import skeleton
from recon.body.base import BodyModel
from recon.export.bvh import write_bvh
from recon.export.glb import INFLUENCES, write_glb
from recon.export.media import write_image
from recon.export.records import write_json
from recon.garment.morph import outfit_animation
from recon.render.raster import Rasterizer, look_at

MAX_DRAWN_GAP = 1.0  # seconds: a longer bridged gap is left out of the overlay
ALPHA_SEEN, ALPHA_BRIDGED = 0.75, 0.35  # the bodies' opacity over the frame
CHUNK = 30  # frames of a track's vertices made at once for the overlay
COLOURS = ((0.45, 0.62, 0.92, 1.0), (0.92, 0.55, 0.45, 1.0), (0.5, 0.82, 0.5, 1.0), (0.85, 0.75, 0.4, 1.0),
           (0.7, 0.5, 0.85, 1.0))


@dataclass
class WorldMotion:
    """One track's motion in its world frame over positions first..first+T-1 of the frames taken."""

    id: int
    first: int
    rotmats: np.ndarray  # (T, 24, 3, 3) local; the root into the world frame
    translation: np.ndarray  # (T, 3) pelvis, world frame
    shape: np.ndarray  # (S,)
    seen: np.ndarray  # (T,) bool
    planted: np.ndarray  # (T, 2) bool
    to_world: tuple[np.ndarray, np.ndarray]  # (R, o): X_world = R @ (X_ref - o), X_ref: the first frame's camera
    # (T, 3, 3) each frame's camera turn from the clip's first camera (x_f = R_f x_ref); None: static
    camera_rotations: np.ndarray | None = None
    # (T, 3) its move where it travelled (X_f = R_f X_ref + t_f for a point); None: it did not
    camera_shifts: np.ndarray | None = None

    def vertices(self, body: BodyModel, f: int, stop: int | None = None) -> np.ndarray:
        """The body's vertices (V, 3) in frame ``f``, world frame; with ``stop``: frames f..stop-1
        (stop - f, V, 3) in one call."""
        last = f + 1 if stop is None else stop
        with torch.no_grad():
            o = body(torch.tensor(self.rotmats[f:last], dtype=torch.float32),
                     torch.tensor(self.shape[None], dtype=torch.float32),
                     transl=torch.tensor(self.translation[f:last], dtype=torch.float32))
        v = o.vertices.numpy().astype(np.float64)
        return v[0] if stop is None else v

    def to_reference(self, x: np.ndarray) -> np.ndarray:
        """World frame -> the clip's first camera (the camera's, where it did not turn)."""
        r, o = self.to_world
        return x @ r + o

    def to_camera(self, x: np.ndarray, f: int | None = None) -> np.ndarray:
        """World frame -> the camera of track frame ``f`` (OpenCV); ``f`` may be left out only
        where the camera did not turn."""
        return self.reference_to_camera(self.to_reference(x), f)

    def reference_to_camera(self, x: np.ndarray, f: int | None = None) -> np.ndarray:
        """The clip's first camera -> the camera of track frame ``f`` (``to_camera``)."""
        if self.camera_rotations is None:
            return x
        if f is None:
            raise ValueError("the camera turned in this clip: say which frame's camera")
        x = x @ self.camera_rotations[f].T
        return x if self.camera_shifts is None else x + self.camera_shifts[f]

    def world_to_camera(self) -> tuple[np.ndarray, np.ndarray]:
        """(T, 3, 3), (T, 3): each frame's X_camera = R @ X_world + t."""
        r, o = self.to_world
        turns = self.camera_rotations if self.camera_rotations is not None else np.eye(3)[None].repeat(
            len(self.rotmats), 0)
        shifts = 0.0 if self.camera_shifts is None else self.camera_shifts
        return turns @ r.T, turns @ o + shifts


def write_track(folder: Path, body: BodyModel, m: WorldMotion, fps: float, frame_index: list[int],
                frame_time: list[float],
                camera: dict, dresser=None, tightness=None, all_influences: bool = False) -> list[str]:
    """The track's files (module doc) in ``folder``; motion.json last. Returns their names."""
    folder.mkdir(parents=True, exist_ok=True)
    shape = torch.tensor(m.shape, dtype=torch.float32)
    with torch.no_grad():
        rest = body(shape=shape[None]).joints[0].numpy()
    write_bvh(folder / "motion.bvh", list(skeleton.JOINT_NAMES), list(skeleton.JOINT_PARENTS), rest, m.rotmats,
              m.translation, fps=fps)
    rotmats, transl = torch.tensor(m.rotmats, dtype=torch.float32), torch.tensor(m.translation, dtype=torch.float32)
    influences = None if all_influences else INFLUENCES
    outfit = None if dresser is None else outfit_animation(body, shape, rotmats, transl, dresser, fps, tightness,
                                                          influences)
    write_glb(folder / "animated.glb", body, shape, rotmats, transl, fps, outfit, influences=influences,
              animation_name=f"track_{m.id}")
    with torch.no_grad():
        joints = body(torch.tensor(m.rotmats, dtype=torch.float32), shape[None],
                      transl=torch.tensor(m.translation, dtype=torch.float32)).joints.numpy()
    r = lambda a, d=4: np.round(np.asarray(a, float), d).tolist()  # noqa: E731
    span = slice(m.first, m.first + len(m.rotmats))
    info = {
        "frame": "world: +Y up from the estimated ground (feet on y = 0), Z towards the camera, metres",
        "track": m.id, "fps": fps, "frames": len(m.rotmats),
        "source_frames": frame_index[span], "times": r(frame_time[span], 4),
        "seen": m.seen.astype(int).tolist(), "planted": m.planted.astype(int).tolist(),
        "shape": dict(zip(getattr(body, "shape_names", None) or [f"s{i}" for i in range(len(m.shape))],
                          r(m.shape), strict=True)),
        "camera": {**camera, "world_to_camera": {"R": r(m.to_world[0].T, 6), "t": r(m.to_world[1], 5)},
                   "note": "X_camera = R @ X_world + t (OpenCV camera; where the camera turned, the clip's first "
                           "frame's, and world_to_camera_per_frame has each of the track's frames)",
                   **({} if m.camera_rotations is None else {"world_to_camera_per_frame": dict(zip(
                       ("R", "t"), (r(a, 6) for a in m.world_to_camera()), strict=True))})},
        "joint_names": list(skeleton.JOINT_NAMES),
        "joints3d": r(joints),
        "pose_axis_angle": r(roma.rotmat_to_rotvec(torch.tensor(m.rotmats)).numpy()),
        "translation": r(m.translation),
        "files": ["motion.bvh", "animated.glb", "motion.json"],
    }
    write_json(folder / "motion.json", info)
    return info["files"]


class OverlayFrames:
    """``overlay(rgb, position) -> frame``: the bodies of the tracks at that position over the
    frame, beside a 3D view of them on the clip's ground, in its world frame (a fixed camera
    above and in front). Drawn by the fast rasteriser of the synthetic benchmark (flat shading)."""

    def __init__(self, body: BodyModel, tracks: list[WorldMotion], k: np.ndarray, size: tuple[int, int],
                 fps: float = 30.0):
        self.body, self.tracks, self.k = body, tracks, np.asarray(k, float)
        self.drawn = [drawn_frames(t.seen, int(round(MAX_DRAWN_GAP * fps))) for t in tracks]
        self.faces = body.faces.cpu().numpy()
        self.raster = Rasterizer(size[1], size[0])
        self.world = tracks[0].to_world if tracks else (np.eye(3), np.zeros(3))  # the clip's one world frame
        r, o = self.world
        pelvis = np.concatenate([(t.to_reference(t.translation) - o) @ r.T for t in tracks] or [np.zeros((1, 3))])
        lo, hi = pelvis.min(0), pelvis.max(0)
        centre = np.array([(lo[0] + hi[0]) / 2, 0.9, (lo[2] + hi[2]) / 2])
        extent = float(max(hi[0] - lo[0], hi[2] - lo[2], 1.0))
        yaw = np.radians(25.0)
        eye = centre + (0.8 * extent + 2.5) * np.array([np.sin(yaw), 0.35, np.cos(yaw)])
        self.view = look_at(eye, centre)
        self.view_k = np.array([[0.9 * size[0], 0, size[1] / 2], [0, 0.9 * size[0], size[0] / 2], [0, 0, 1.0]])
        half = 2.0 * extent + 4.0
        corners = np.array([[-half, 0, -half], [half, 0, -half], [half, 0, half], [-half, 0, half]])
        self.floor = (corners + centre * [1, 0, 1], np.array([[0, 2, 1], [0, 3, 2]]))
        self._chunks: dict[int, tuple[int, np.ndarray]] = {}  # per track: first frame, vertices

    def __call__(self, rgb: np.ndarray, position: int) -> np.ndarray:
        r, o = self.world
        cam_v, world_v, colours, alpha = [], [], [], []
        for n, (t, drawn) in enumerate(zip(self.tracks, self.drawn, strict=True)):
            f = position - t.first
            if 0 <= f < len(t.rotmats) and drawn[f]:
                v = t.to_reference(self._vertices(n, f))
                cam_v.append(t.reference_to_camera(v, f))
                world_v.append((v - o) @ r.T)
                colours.append(COLOURS[t.id % len(COLOURS)][:3])
                alpha.append(ALPHA_SEEN if t.seen[f] else ALPHA_BRIDGED)
        left = rgb.copy()
        if cam_v:
            img, labels, _ = self._draw(cam_v, colours, self.k)
            rows, cols = np.flatnonzero((labels >= 0).any(1)), np.flatnonzero((labels >= 0).any(0))
            if len(rows):  # blended within the bodies' bounding box only
                box = np.s_[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
                lab, under, over, out = labels[box], rgb[box], img[box], left[box]
                hit = lab >= 0
                a = np.asarray(alpha, np.float32)[lab[hit]][:, None]
                out[hit] = ((1 - a) * under[hit] + a * over[hit] + 0.5).astype(np.uint8)
        fv, ff = self.floor
        vr, vt = self.view
        img, labels, _ = self._draw([*world_v, fv], [*colours, (0.8, 0.8, 0.78)], self.view_k, vr, vt,
                                    extra_faces=ff)
        out = np.empty((rgb.shape[0], 2 * rgb.shape[1], 3), np.uint8)
        out[:, :rgb.shape[1]] = left
        out[:, rgb.shape[1]:] = np.where((labels >= 0)[..., None], img, np.uint8(255))
        return out

    def _vertices(self, n: int, f: int) -> np.ndarray:
        """Track ``n``'s vertices in its frame ``f``, made ``CHUNK`` frames at a time (frames are
        drawn in order)."""
        start, verts = self._chunks.get(n, (0, np.zeros((0, 0, 3))))
        if not start <= f < start + len(verts):
            t = self.tracks[n]
            start, verts = f, t.vertices(self.body, f, min(f + CHUNK, len(t.rotmats)))
            self._chunks[n] = (start, verts)
        return verts[f - start]

    def _draw(self, meshes: list[np.ndarray], colours, k, rot=None, tr=None, extra_faces=None):
        """Bodies (and last, with ``extra_faces``, the floor) through the rasteriser; (R, t): the
        world -> camera transform of the 3D view."""
        verts, faces, cols, ids, n = [], [], [], [], 0
        for i, (v, c) in enumerate(zip(meshes, colours, strict=True)):
            f = extra_faces if (extra_faces is not None and i == len(meshes) - 1) else self.faces
            verts.append(v if rot is None else v @ rot.T + tr)
            faces.append(f + n)
            cols.append(np.tile(np.asarray(c, np.float32), (len(v), 1)))
            ids.append(np.full(len(v), i, np.int32))  # the labels image says which mesh a pixel shows
            n += len(v)
        return self.raster.render(np.concatenate(verts), np.concatenate(faces), k, np.concatenate(cols),
                                  np.concatenate(ids), light_dir=(0.3, -0.6, -1.0),
                                  ambient=0.45)  # towards the light: up, front

    def close(self) -> None:
        pass


PORTRAIT_HEIGHT = 256  # px: the most a track's portrait is tall


def write_portrait(path: Path, rgb: np.ndarray, box) -> None:
    """The person in ``box`` (x0, y0, x1, y1) of frame ``rgb``, with a margin, at most
    ``PORTRAIT_HEIGHT`` pixels tall: who a track is, on the results page."""
    h, w = rgb.shape[:2]
    x0, y0, x1, y1 = np.asarray(box, float)
    m = 0.1 * max(x1 - x0, y1 - y0)
    x0, y0 = int(max(0, x0 - m)), int(max(0, y0 - m))
    x1, y1 = int(min(w, x1 + m)), int(min(h, y1 + m))
    crop = rgb[y0:max(y1, y0 + 1), x0:max(x1, x0 + 1)]
    scale = min(1.0, PORTRAIT_HEIGHT / crop.shape[0])
    if scale < 1.0:
        crop = cv2.resize(crop, (max(1, round(crop.shape[1] * scale)), PORTRAIT_HEIGHT), interpolation=cv2.INTER_AREA)
    write_image(path, np.ascontiguousarray(crop))


def drawn_frames(seen: np.ndarray, max_gap: int) -> np.ndarray:
    """(T,) bool: the frames seen, and those of gaps of at most ``max_gap`` frames between them."""
    drawn = seen.astype(bool).copy()
    idx = np.flatnonzero(seen)
    for a, b in zip(idx[:-1], idx[1:], strict=True):
        if 1 < b - a <= max_gap + 1:
            drawn[a + 1:b] = True
    return drawn
