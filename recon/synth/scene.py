"""SURREAL-like synthetic samples of the body model.

A sample = a posed, shaped body with clothing-like colours seen by a random pinhole camera over
a background (skimage's photos without people, or procedural), with random occluders. Every
random choice of sample ``i`` comes from ``np.random.default_rng([seed, i])`` so a sample is
reproducible on its own, whatever the worker count.

Camera: OpenCV (x right, y down, z forward). Body frame -> camera: X_cam = R @ X_body + t.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np
import roma
import skimage.data
import torch
from anny.shape_distribution import SimpleShapeDistribution
from scipy.spatial.transform import Rotation

from recon import camera
from recon.body import skeleton
from recon.body.base import BodyModel
from recon.poses.sampler import PoseSampler, ShapeSampler
from recon.render.raster import Rasterizer
from recon.synth.clothes import Wardrobe

BACKGROUNDS = ("brick", "chelsea", "coffee", "grass", "gravel", "rocket", "cat", "clock", "coins", "colorwheel",
               "moon", "page", "text", "hubble_deep_field", "immunohistochemistry", "retina", "checkerboard")
SKIN_TONES = np.array([[0.96, 0.80, 0.69], [0.90, 0.70, 0.56], [0.78, 0.57, 0.42], [0.62, 0.44, 0.30],
                       [0.45, 0.31, 0.21], [0.33, 0.22, 0.15]])
J = {n: i for i, n in enumerate(skeleton.JOINT_NAMES)}
TOP = [J[n] for n in ("spine1", "spine2", "spine3", "left_collar", "right_collar", "left_shoulder", "right_shoulder")]
SLEEVE = [J[n] for n in ("left_elbow", "right_elbow")]
BOTTOM = [J[n] for n in ("pelvis", "left_hip", "right_hip")]
LEG = [J[n] for n in ("left_knee", "right_knee")]
FEET = [J[n] for n in ("left_ankle", "right_ankle", "left_foot", "right_foot")]


@dataclass
class SynthConfig:
    size: int = 256
    focal_range: tuple[float, float] = (300.0, 700.0)  # pixels, for `size`
    fill_range: tuple[float, float] = (0.55, 0.9)  # body height / image height
    shift: float = 0.08  # the body's centre lands within this fraction of the image size of the centre
    elevation_sigma_deg: float = 12.0
    roll_sigma_deg: float = 4.0
    occluder_prob: float = 0.5
    pose_noise_deg: float = 8.0
    # domain randomisation (0.12; the defaults render the benchmarks as before): the share of people
    # dressed in CLOTH3D outfits of the training distribution (recon.synth.clothes), how many such
    # outfits a stream draws, and bodies of any anny shape (gender anywhere in [0, 1], ages 18-80)
    dressed_prob: float = 0.0
    outfits: int = 12
    any_shape: bool = False


@cache
def _background_image(name: str) -> np.ndarray:
    im = getattr(skimage.data, name)()
    if im.ndim == 2:
        im = np.repeat(im[..., None], 3, axis=2)
    return np.ascontiguousarray(im[..., :3].astype(np.uint8))


def background(rng: np.random.Generator, size: int) -> np.ndarray:
    if rng.random() < 0.7:
        im = _background_image(BACKGROUNDS[rng.integers(len(BACKGROUNDS))]).astype(np.float32)
        h, w = im.shape[:2]
        c = int(rng.uniform(0.4, 1.0) * min(h, w))
        y, x = rng.integers(0, h - c + 1), rng.integers(0, w - c + 1)
        im = cv2.resize(im[y:y + c, x:x + c], (size, size), interpolation=cv2.INTER_AREA)
        im = im * rng.uniform(0.6, 1.3, 3)  # colour cast
        if rng.random() < 0.5:
            im = im[:, ::-1]
    else:  # procedural: gradient + blobs + noise
        g = np.linspace(0, 1, size, dtype=np.float32)
        a, b = rng.uniform(0, 255, 3), rng.uniform(0, 255, 3)
        t = g[:, None, None] if rng.random() < 0.5 else g[None, :, None]
        im = a * (1 - t) + b * t + np.zeros((size, size, 3), np.float32)
        for _ in range(rng.integers(0, 6)):
            cv2.circle(im, tuple(int(v) for v in rng.integers(0, size, 2)), int(rng.integers(5, size // 3)),
                       tuple(float(v) for v in rng.uniform(0, 255, 3)), -1)
        im += rng.normal(0, rng.uniform(0, 20), im.shape).astype(np.float32)
    return np.clip(im, 0, 255).astype(np.uint8)


CLOTH_LABEL = 1000  # the rasteriser's label of cloth (parts: 25 = cloth, after the 24 body parts)


def garment_colours(rng: np.random.Generator, rest: np.ndarray) -> np.ndarray:
    """One garment's colours (N, 3): plain, striped or mottled, as the painted clothes."""
    base = rng.uniform(0.05, 0.95, 3)
    kind = rng.integers(3)
    if kind == 1:
        f, ax = rng.uniform(10, 60), rng.integers(3)
        mod = 0.5 + 0.5 * np.sign(np.sin(f * rest[:, ax]))
        col = base * (0.55 + 0.45 * mod[:, None])
    elif kind == 2:
        col = base * rng.uniform(0.7, 1.1, (len(rest), 1))
    else:
        col = np.tile(base, (len(rest), 1))
    return np.clip(col, 0, 1).astype(np.float32)


def vertex_colours(rng: np.random.Generator, rest_vertices: np.ndarray, parts: np.ndarray) -> np.ndarray:
    """Skin tone everywhere, then a top (optional sleeves), a bottom (optional legs) and shoes,
    each plain, striped or noisy, drawn on the rest-pose coordinates."""
    col = np.tile(SKIN_TONES[rng.integers(len(SKIN_TONES))] * rng.uniform(0.9, 1.1, 3), (len(parts), 1))

    def garment(joints):
        base = rng.uniform(0.05, 0.95, 3)
        m = np.isin(parts, joints)
        kind = rng.integers(3)
        if kind == 1:  # stripes
            f, ax = rng.uniform(10, 60), rng.integers(3)
            mod = 0.5 + 0.5 * np.sign(np.sin(f * rest_vertices[m, ax]))
            col[m] = base * (0.55 + 0.45 * mod[:, None])
        elif kind == 2:  # mottled
            col[m] = base * rng.uniform(0.7, 1.1, (m.sum(), 1))
        else:
            col[m] = base

    garment(TOP + (SLEEVE if rng.random() < 0.5 else []))
    garment(BOTTOM + (LEG if rng.random() < 0.6 else []))
    garment(FEET)
    return np.clip(col, 0, 1).astype(np.float32)


def sample_camera(rng: np.random.Generator, cfg: SynthConfig, body_height: float):
    """Intrinsics K and the body -> camera rotation R and translation t of one sample: the camera
    faces the subject's front (``recon.camera.HALF_TURN_X``), tilted by elevation and roll."""
    f = rng.uniform(*cfg.focal_range)
    fill = rng.uniform(*cfg.fill_range)
    dist = f * body_height / (fill * cfg.size)
    elev = np.clip(rng.normal(0, cfg.elevation_sigma_deg), -35, 35)
    roll = np.clip(rng.normal(0, cfg.roll_sigma_deg), -15, 15)
    r = Rotation.from_euler("zx", [roll, elev], degrees=True).as_matrix() @ camera.HALF_TURN_X
    shift = rng.uniform(-cfg.shift, cfg.shift, 2) * cfg.size * dist / f  # metres
    t = np.array([shift[0], shift[1], dist])
    k = np.array([[f, 0, cfg.size / 2], [0, f, cfg.size / 2], [0, 0, 1.0]])
    return k, r, t


def occlude(rng: np.random.Generator, rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Paint 1-3 random shapes over the person's box; returns the occluder mask."""
    occ = np.zeros(mask.shape, np.uint8)
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return occ.astype(bool)
    x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
    for _ in range(rng.integers(1, 4)):
        cx, cy = rng.integers(x0, x1 + 1), rng.integers(y0, y1 + 1)
        rad = int(rng.uniform(0.05, 0.25) * max(x1 - x0, y1 - y0, 8))
        colour = tuple(float(v) for v in rng.uniform(0, 255, 3))
        shape = np.zeros_like(occ)
        if rng.random() < 0.5:
            axes = (rad, int(rad * rng.uniform(0.3, 1.5)))
            cv2.ellipse(shape, (int(cx), int(cy)), axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
        else:
            cv2.rectangle(shape, (int(cx - rad), int(cy - rad // 2)), (int(cx + rad), int(cy + rad // 2)), 1, -1)
        rgb[shape > 0] = colour
        occ |= shape
    return occ.astype(bool)


class SceneSampler:
    """Draws and renders sample ``i`` of a (split, seed) stream.

    Poses and shapes are drawn once per (split, seed) into pools (``pool`` collision-free
    poses, 4,096 shapes), batch-sampled for speed; sample i picks from them with its own RNG
    and adds a random yaw, so it stays reproducible on its own."""

    def __init__(self, body: BodyModel, split: str, seed: int, cfg: SynthConfig | None = None, pool: int = 4096):
        cfg = cfg or SynthConfig()
        self.split, self.seed, self.cfg = split, seed, cfg
        # the geometry in float64: rounded to float32 it is the same on every CPU's float kernels
        self.body = copy.deepcopy(body).double()
        self.pose_pool = PoseSampler(self.body, split=split, noise_deg=cfg.pose_noise_deg, seed=seed).sample(pool)
        self.shape_pool = ShapeSampler(self.body, seed=seed).sample(4096)
        self.parts = body.weights.argmax(1).numpy()
        self.faces = body.faces.numpy()
        self.raster = Rasterizer(cfg.size, cfg.size)
        self.wardrobe = Wardrobe(self.body, seed, cfg.outfits, presets=False, held_out=False) \
            if cfg.dressed_prob > 0 else None
        self.age_map = SimpleShapeDistribution(body.anny).morphological_age_mapping \
            if cfg.any_shape and hasattr(body, "anny") else None

    def any_shape(self, rng: np.random.Generator) -> torch.Tensor:
        """(1, S) every phenotype uniform in [0, 1], the age uniform over 18-80 years."""
        names = list(self.body.shape_names)
        s = rng.uniform(0.0, 1.0, len(names))
        if self.age_map is not None and "age" in names:
            years = torch.tensor([rng.uniform(18.0, 80.0)], dtype=torch.float32)
            s[names.index("age")] = float(self.age_map.morphological_to_anny_age(years)[0])
        return torch.tensor(s, dtype=torch.float32)[None]

    def dress(self, rng: np.random.Generator, pose: torch.Tensor, shape: torch.Tensor, out, v: np.ndarray,
              colours: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The body with an outfit of the wardrobe on (``dressed_prob``): (vertices, faces, colours,
        labels), the cloth after the body, labelled ``CLOTH_LABEL``."""
        labels = self.parts
        if self.wardrobe is None or rng.random() >= self.cfg.dressed_prob:
            return v, self.faces, colours, labels
        k = int(rng.integers(len(self.wardrobe.outfits)))
        o = self.wardrobe.outfits[k]
        rot = roma.rotvec_to_rotmat(pose.double())
        cloth = self.wardrobe.dress(k, rot, shape.double(), out, rng.uniform(0.0, 0.3))
        col = np.zeros((len(cloth), 3), np.float32)
        rest = o.model.rest.numpy()
        for g in np.unique(o.garment_id):
            m = o.garment_id == g
            col[m] = garment_colours(rng, rest[m])
        return (np.concatenate([v, cloth]), np.concatenate([self.faces, o.faces + len(v)]),
                np.concatenate([colours, col]), np.concatenate([labels, np.full(len(cloth), CLOTH_LABEL)]))

    def sample(self, i: int) -> dict[str, np.ndarray]:
        rng = np.random.default_rng([self.seed, i])
        pose = self.pose_pool[int(rng.integers(len(self.pose_pool)))][None].clone()
        yaw = Rotation.from_euler("y", rng.uniform(-180, 180), degrees=True)
        pose[0, 0] = torch.tensor((yaw * Rotation.from_rotvec(pose[0, 0].numpy())).as_rotvec(), dtype=torch.float32)
        shape = self.shape_pool[int(rng.integers(len(self.shape_pool)))][None]
        if self.cfg.any_shape:
            shape = self.any_shape(rng)
        with torch.no_grad():
            out = self.body(pose.double(), shape.double())
        v = out.vertices[0].numpy().astype(np.float64)
        k, r, t = sample_camera(rng, self.cfg, float(v[:, 1].max() - v[:, 1].min()))
        to_cam = lambda p: p @ r.T + t  # noqa: E731
        colours = vertex_colours(rng, out.rest_vertices[0].numpy(), self.parts)
        mesh_v, mesh_f, colours, mesh_l = self.dress(rng, pose, shape, out, v, colours) \
            if self.wardrobe is not None else (v, self.faces, colours, self.parts)
        light = rng.normal(0, 1, 3) * [1, 1, 0.3] + [0, 0, 1.0]
        rgb, labels, depth = self.raster.render(to_cam(mesh_v), mesh_f, k, colours, mesh_l, light_dir=-light,
                                                ambient=rng.uniform(0.3, 0.6))
        person = labels >= 0
        if len(mesh_v) > len(v):  # dressed: the body's own silhouette for IoU, the person's for the mask
            sil = self.raster.render(to_cam(v), self.faces, k, None, self.parts)[1] >= 0
            labels = np.where(labels == CLOTH_LABEL, len(skeleton.JOINT_NAMES), labels)
        else:
            sil = person
        img = background(rng, self.cfg.size)
        img[sil] = rgb[sil]
        occ = occlude(rng, img, sil) if rng.random() < self.cfg.occluder_prob else np.zeros_like(sil)
        grain = rng.standard_normal(img.shape, dtype=np.float32) * np.float32(rng.uniform(0, 6))
        img = np.clip(img.astype(np.float32) * np.float32(rng.uniform(0.8, 1.2)) + grain, 0, 255)
        pts = to_cam(out.points[0].numpy().astype(np.float64))
        return {
            "rgb": img.astype(np.uint8), "mask": person & ~occ, "silhouette": sil,
            "parts": np.where(person, labels + 1, 0).astype(np.uint8), "depth": depth.astype(np.float16),
            "K": k.astype(np.float32), "R": r.astype(np.float32), "t": t.astype(np.float32),
            "points3d": pts.astype(np.float32), "points2d": camera.project(pts, k).astype(np.float32),
            "pose": pose[0].numpy(), "shape": shape[0].numpy(),
            "vertices": (v - v[:1] * 0 - out.joints[0, :1].numpy()).astype(np.float16),
        }
