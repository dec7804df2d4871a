"""The other domain: people rendered unlike the training data, to choose and report on.

Every choice of the image -> body stage is made on ``other-val`` and reported on ``other-test``
(``recon.synth.dataset.BENCHMARKS``), never on the training generator's own look
(``recon.synth.scene``). What differs from it:

- renderer: smooth per-vertex shading under three coloured lights and a sky/ground ambient,
  highlights, anti-aliasing (``recon.render.look``); the training renders are flat-shaded faces;
- clothes: draped garments (the five PBNS presets, looser or tighter, and held-out CLOTH3D-style
  outfits animated by DeePSD; ``recon.synth.clothes``) with printed patterns, hair and shoes; the
  training bodies wear painted colours;
- backgrounds: real photographs from Debian packages the training data never uses
  (``recon.synth.photos``), sometimes out of focus; occluders cut from other photographs;
- bodies: every anny shape (gender anywhere in [0, 1], every height, weight, muscle and proportion,
  ages 18-80);
- framing: 640 x 480 or 480 x 640 frames, the person 30-90 % of the frame's height anywhere in
  it, a third of them cut by a border, focal 0.6-1.6 x the long side, any view (back and side as
  often as front), camera pitch and roll;
- camera: white balance, vignetting, sensor noise, JPEG compression (quality 40-95; the stored
  image is that JPEG).

Sample i depends only on (split, seed, i): ``np.random.default_rng([seed, i])``; the geometry is
computed in float64 and the pixels with exactly rounded operations, so a sample is the same bits
on the same CPU kernels; under others a few pixels of some images move (``clothes``).
``EmptySampler``: the same frames without a person; ``CrowdSampler``: street scenes with 4-10
people.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import cv2
import numpy as np
import roma
import torch
from anny import KeypointsRegressor
from anny.shape_distribution import SimpleShapeDistribution
from scipy.spatial.transform import Rotation

from recon import camera
from recon.body.base import BodyModel
from recon.poses.sampler import PoseSampler
from recon.render import look
from recon.render.normals import vertex_normals
from recon.render.raster import Rasterizer
from recon.synth import photos
from recon.synth.clothes import Wardrobe

GARMENT_LABEL = 24  # the parts image's label of clothes (body parts are 0-23)


@dataclass
class OtherConfig:
    size: tuple[int, int] = (640, 480)  # (W, H) of a landscape frame; portraits swap them
    portrait_prob: float = 0.35
    fill_range: tuple[float, float] = (0.3, 0.9)  # the body's height / the frame's height
    cut_prob: float = 1 / 3  # the share of people cut by a border
    focal_range: tuple[float, float] = (0.6, 1.6)  # x the frame's long side
    pitch_sigma_deg: float = 10.0
    roll_sigma_deg: float = 3.0
    dressed_prob: float = 0.85  # else painted clothes (tight sportswear)
    occluder_prob: float = 0.2
    defocus_prob: float = 0.4  # the background out of focus
    random_outfits: int = 8  # held-out CLOTH3D outfits in the wardrobe, beside the five presets
    age_range: tuple[float, float] = (18.0, 80.0)


def double_k(k: np.ndarray) -> np.ndarray:
    """The intrinsics of the same camera at twice the resolution (pixel centres at integers)."""
    k2 = k.copy()
    k2[:2, :2] *= 2
    k2[:2, 2] = 2 * k[:2, 2] + 0.5
    return k2


class OtherSceneSampler:
    """Draws and renders sample ``i`` of the other domain's (split, seed) stream; ``body`` is the
    body model (anny)."""

    def __init__(self, body: BodyModel, split: str, seed: int, cfg: OtherConfig | None = None, pool: int = 2048):
        cfg = cfg or OtherConfig()
        self.split, self.seed, self.cfg = split, seed, cfg
        self.body = copy.deepcopy(body).double()
        self.pose_pool = PoseSampler(self.body, split=split, noise_deg=8.0, seed=seed + 17).sample(pool)
        self.age_map = SimpleShapeDistribution(body.anny).morphological_age_mapping if hasattr(body, "anny") else None
        self.wardrobe = Wardrobe(self.body, seed, cfg.random_outfits)
        self.parts = body.weights.argmax(1).numpy()
        # the rest nose and eyes: anny's COCO keypoint regressor's first three rows (V weights each)
        self.face = (KeypointsRegressor.coco(body.anny).regression_weights[:3].double().numpy()
                     if hasattr(body, "anny") else np.zeros((3, len(self.parts))))
        self.faces = body.faces.numpy()
        self.photo_names = photos.other_photo_names()
        self.raster = Rasterizer(*self.cfg.size)

    # --- drawing ------------------------------------------------------------------------------
    def shape(self, rng: np.random.Generator) -> torch.Tensor:
        """(1, S) every anny phenotype uniform in [0, 1], the age uniform over ``age_range`` years."""
        names = list(self.body.shape_names)
        s = rng.uniform(0.0, 1.0, len(names))
        if self.age_map is not None and "age" in names:
            years = torch.tensor([rng.uniform(*self.cfg.age_range)], dtype=torch.float32)
            s[names.index("age")] = float(self.age_map.morphological_to_anny_age(years)[0])
        return torch.tensor(s, dtype=torch.float64)[None]

    def pose(self, rng: np.random.Generator) -> torch.Tensor:
        pose = self.pose_pool[int(rng.integers(len(self.pose_pool)))][None].double().clone()
        yaw = Rotation.from_euler("y", rng.uniform(-180, 180), degrees=True)
        pose[0, 0] = torch.tensor((yaw * Rotation.from_rotvec(pose[0, 0].numpy())).as_rotvec())
        return pose

    def photo(self, rng: np.random.Generator) -> np.ndarray:
        return photos.load_photo(self.photo_names[int(rng.integers(len(self.photo_names)))])

    def person(self, rng: np.random.Generator):
        """A posed, shaped, dressed body: (pose, shape, body output, vertices (V', 3) body frame,
        faces, albedo (V', 3), specular (V',), shininess (V',), labels (V',)), body vertices first."""
        pose, shape = self.pose(rng), self.shape(rng)
        rot = roma.rotvec_to_rotmat(pose)
        with torch.no_grad():
            out = self.body(rot, shape)
        v = out.vertices[0].numpy()
        with torch.no_grad():
            rest_v, rest_j = (x[0].numpy() for x in self.body.rest_geometry(shape))
        albedo = look.body_albedo(rng, rest_v, self.parts, rest_j, self.face @ rest_v)
        spec = np.full(len(v), rng.uniform(0.03, 0.12))
        shin = np.full(len(v), 16, np.int64)
        labels = self.parts.astype(np.int32)
        faces = self.faces
        outfit = -1
        if rng.random() < self.cfg.dressed_prob:
            outfit = int(rng.integers(len(self.wardrobe.outfits)))
            o = self.wardrobe.outfits[outfit]
            loose = rng.uniform(0.0, 0.35) if rng.random() < 0.6 else 0.0
            cloth = self.wardrobe.dress(outfit, rot, shape, out, loose)
            rest_c = o.model.rest.numpy()
            c_alb = np.zeros((len(cloth), 3))
            c_spec, c_shin = np.zeros(len(cloth)), np.zeros(len(cloth), np.int64)
            for g in np.unique(o.garment_id):
                m = o.garment_id == g
                c_alb[m] = look.pattern(rng, rest_c[m], self.photo(rng))
                c_spec[m] = rng.uniform(0.0, 0.2)
                c_shin[m] = int(rng.choice([4, 8, 16, 32]))
            faces = np.concatenate([faces, o.faces + len(v)])
            v = np.concatenate([v, cloth])
            albedo, spec = np.concatenate([albedo, c_alb]), np.concatenate([spec, c_spec])
            shin = np.concatenate([shin, c_shin])
            labels = np.concatenate([labels, np.full(len(cloth), GARMENT_LABEL, np.int32)])
        else:  # painted tight clothes: a top and a bottom over the skin
            for joints in (look.TOP_JOINTS, look.BOTTOM_JOINTS):
                m = np.isin(self.parts, joints)
                albedo[m] = look.pattern(rng, rest_v[m], self.photo(rng))
        return pose, shape, out, v, faces, albedo, spec, shin, labels, outfit

    def camera(self, rng: np.random.Generator, v_body: np.ndarray, w: int, h: int):
        """K, R, t (body -> OpenCV camera) framing the body as the config says, and the share of
        its box outside the frame."""
        cfg = self.cfg
        f = rng.uniform(*cfg.focal_range) * max(w, h)
        fill = rng.uniform(*cfg.fill_range)
        height = float(v_body[:, 1].max() - v_body[:, 1].min())
        dist = f * height / (fill * h)
        pitch = np.clip(rng.normal(0, cfg.pitch_sigma_deg), -30, 30)
        roll = np.clip(rng.normal(0, cfg.roll_sigma_deg), -10, 10)
        r = Rotation.from_euler("zx", [roll, pitch], degrees=True).as_matrix() @ camera.HALF_TURN_X
        k = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
        p = v_body @ r.T + [0.0, 0.0, dist]
        uv = camera.project(p, k)
        lo, hi = uv.min(0), uv.max(0)
        size, centre = hi - lo, 0.5 * (lo + hi)
        target = np.array([rng.uniform(min(size[0] / 2, w / 2), max(w - size[0] / 2, w / 2)),
                           rng.uniform(min(size[1] / 2, h / 2), max(h - size[1] / 2, h / 2))])
        if rng.random() < cfg.cut_prob:
            side = rng.choice(4, p=[0.3, 0.3, 0.3, 0.1])  # left, right, bottom, top
            frac = rng.uniform(0.1, 0.4)  # of the box outside: most of the person stays in view
            if side == 0:
                target[0] = -frac * size[0] + size[0] / 2
            elif side == 1:
                target[0] = w + frac * size[0] - size[0] / 2
            elif side == 2:
                target[1] = h + frac * size[1] - size[1] / 2
            else:
                target[1] = -frac * size[1] + size[1] / 2
        shift = (target - centre) * dist / f
        t = np.array([shift[0], shift[1], dist])
        uv = camera.project(v_body @ r.T + t, k)
        lo, hi = uv.min(0), uv.max(0)
        inside = (np.clip(hi, 0, [w, h]) - np.clip(lo, 0, [w, h])).clip(0).prod()
        cut = 1.0 - float(inside / max((hi - lo).prod(), 1e-9))
        return k, r, t, cut

    def background(self, rng: np.random.Generator, w: int, h: int) -> np.ndarray:
        bg = look.photo_crop(rng, self.photo(rng), w, h)
        if rng.random() < self.cfg.defocus_prob:
            bg = cv2.GaussianBlur(bg, (0, 0), rng.uniform(1.0, 4.0))
        return bg

    def occlude(self, rng: np.random.Generator, img: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """A piece of another photograph (a box or an ellipse) over part of the person; its mask."""
        ys, xs = np.nonzero(mask)
        occ = np.zeros(mask.shape, np.uint8)
        if len(xs) == 0:
            return occ.astype(bool)
        x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
        size = max(x1 - x0, y1 - y0, 8)
        cx, cy = rng.integers(x0, x1 + 1), rng.integers(y0, y1 + 1)
        a, b = int(rng.uniform(0.05, 0.2) * size), int(rng.uniform(0.05, 0.2) * size)
        if rng.random() < 0.5:
            cv2.ellipse(occ, (int(cx), int(cy)), (a, b), float(rng.uniform(0, 180)), 0, 360, 1, -1)
        else:
            cv2.rectangle(occ, (int(cx - a), int(cy - b)), (int(cx + a), int(cy + b)), 1, -1)
        patch = look.photo_crop(rng, self.photo(rng), img.shape[1], img.shape[0])
        img[occ > 0] = patch[occ > 0]
        return occ.astype(bool)

    # --- rendering ----------------------------------------------------------------------------
    def draw(self, k, r, t, v_body, faces, albedo, spec, shin, labels, light, bg):
        """The anti-aliased person over ``bg`` (its size is the frame's); labels and depth at 1x."""
        h, w = bg.shape[:2]
        vc = v_body @ r.T + t
        normals = vertex_normals(vc, faces)
        colours = look.shade(vc, normals, albedo, spec, shin, light)
        rgb2, lab2, _ = self.raster.set_size(2 * w, 2 * h).render(vc, faces, double_k(k), colours, labels, flat=False)
        img = look.composite2(rgb2, lab2 >= 0, bg)
        _, lab, depth = self.raster.set_size(w, h).render(vc, faces, k, None, labels)
        return img, lab, depth

    def sample(self, i: int) -> dict:
        rng = np.random.default_rng([self.seed, i])
        w, h = self.cfg.size
        if rng.random() < self.cfg.portrait_prob:
            w, h = h, w
        pose, shape, out, v, faces, albedo, spec, shin, labels, outfit = self.person(rng)
        nb = out.vertices.shape[1]
        k, r, t, cut = self.camera(rng, v[:nb], w, h)
        light = look.lights(rng)
        bg = self.background(rng, w, h)
        img, lab, depth = self.draw(k, r, t, v, faces, albedo, spec, shin, labels, light, bg)
        body_lab = self.raster.set_size(w, h).render(v[:nb] @ r.T + t, self.faces, k, None, self.parts)[1]
        sil = body_lab >= 0
        person = lab >= 0
        occ = self.occlude(rng, img, person) if rng.random() < self.cfg.occluder_prob else np.zeros_like(person)
        img, quality = look.camera_effects(rng, img)
        data = look.jpeg(img, quality)
        pts = out.points[0].numpy() @ r.T + t
        facing = r @ out.global_rotmats[0, 0].numpy() @ np.array([0.0, 0.0, 1.0])  # the body's forward
        to_cam = -(out.joints[0, 0].numpy() @ r.T + t)
        yaw = np.degrees(np.arctan2(facing[0] * to_cam[2] - facing[2] * to_cam[0],
                                    facing[0] * to_cam[0] + facing[2] * to_cam[2]))
        return {
            "rgb": look.unjpeg(data), "rgb_jpg": data, "mask": person & ~occ, "silhouette": sil,
            "parts": np.where(lab >= 0, lab + 1, 0).astype(np.uint8), "depth": depth.astype(np.float16),
            "K": k.astype(np.float32), "R": r.astype(np.float32), "t": t.astype(np.float32),
            "points3d": pts.astype(np.float32), "points2d": camera.project(pts, k).astype(np.float32),
            "pose": pose[0].float().numpy(), "shape": shape[0].float().numpy(),
            "vertices": (v[:nb] - out.joints[0, :1].numpy()).astype(np.float16),
            # view: 0 front, +-180 back; cut: share of the box outside the frame
            "info": np.array([yaw, cut, outfit, quality, h / w], np.float32),
        }
