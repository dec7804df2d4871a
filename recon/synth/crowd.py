"""Other-domain frames without a person, and street scenes with several people.

``EmptySampler``: the other domain's backgrounds (``recon.synth.other``: real photographs, a piece
of another photograph pasted on, the same camera), where no body may be found.
``CrowdSampler``: 4-10 people of the other domain standing on a ground plane in front of a
street-like photograph, 60-400 px tall, nearer people hiding farther ones; the truth per person:
J+ 2D, box, height in pixels, the visible share of its silhouette.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from recon import camera
from recon.body.base import BodyModel
from recon.render import look
from recon.render.normals import vertex_normals
from recon.synth import photos
from recon.synth.other import OtherConfig, OtherSceneSampler, double_k

MAX_PEOPLE = 10


class EmptySampler:
    """Sample i: a person-free other-domain frame (rgb, its JPEG, K)."""

    def __init__(self, body: BodyModel, split: str, seed: int, cfg: OtherConfig | None = None):
        self.seed, self.cfg = seed, cfg or OtherConfig()
        self.names = photos.other_photo_names()

    def sample(self, i: int) -> dict:
        rng = np.random.default_rng([self.seed, i])
        w, h = self.cfg.size
        if rng.random() < self.cfg.portrait_prob:
            w, h = h, w
        img = look.photo_crop(rng, photos.load_photo(self.names[int(rng.integers(len(self.names)))]), w, h)
        if rng.random() < self.cfg.defocus_prob:
            img = cv2.GaussianBlur(img, (0, 0), rng.uniform(1.0, 4.0))
        if rng.random() < 0.5:  # a piece of another photograph, as the occluders of the people
            occ = np.zeros((h, w), np.uint8)
            a, b = int(rng.uniform(0.05, 0.3) * h), int(rng.uniform(0.05, 0.3) * h)
            cv2.ellipse(occ, (int(rng.integers(w)), int(rng.integers(h))), (a, b), float(rng.uniform(0, 180)), 0, 360,
                        1, -1)
            patch = look.photo_crop(rng, photos.load_photo(self.names[int(rng.integers(len(self.names)))]), w, h)
            img[occ > 0] = patch[occ > 0]
        img, quality = look.camera_effects(rng, img)
        data = look.jpeg(img, quality)
        f = rng.uniform(*self.cfg.focal_range) * max(w, h)
        return {"rgb": look.unjpeg(data), "rgb_jpg": data,
                "K": np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]], np.float32),
                "info": np.array([quality], np.float32)}


@dataclass
class CrowdConfig:
    size: tuple[int, int] = (1024, 768)
    people: tuple[int, int] = (4, 10)
    height_px: tuple[float, float] = (60.0, 400.0)  # each person's height in the frame
    focal_range: tuple[float, float] = (0.8, 1.2)  # x the long side
    camera_height: tuple[float, float] = (1.0, 1.7)  # metres above the ground
    pitch_deg: tuple[float, float] = (2.0, 8.0)  # looking down


class CrowdSampler(OtherSceneSampler):
    """Sample i: a street scene of the other domain with several people."""

    def __init__(self, body: BodyModel, split: str, seed: int, cfg: CrowdConfig | None = None, pool: int = 2048,
                 random_outfits: int = OtherConfig.random_outfits):
        super().__init__(body, split, seed, OtherConfig(occluder_prob=0.0, random_outfits=random_outfits), pool)
        self.crowd = cfg or CrowdConfig()
        self.photo_names = list(photos.STREETS)

    def sample(self, i: int) -> dict:
        rng = np.random.default_rng([self.seed, i])
        cc = self.crowd
        w, h = cc.size
        f = rng.uniform(*cc.focal_range) * w
        k = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
        hc = rng.uniform(*cc.camera_height)
        pitch = Rotation.from_euler("x", -rng.uniform(*cc.pitch_deg), degrees=True).as_matrix()
        n = int(rng.integers(cc.people[0], cc.people[1] + 1))
        verts, faces, alb, spec, shin, ids, people = [], [], [], [], [], [], []
        off = 0
        for j in range(n):
            pose, shape, out, v, fc, a, s, sh, _, _ = self.person(rng)
            nb = out.vertices.shape[1]
            p = v @ camera.HALF_TURN_X.T  # body -> a level camera's axes (y down)
            height = float(p[:nb, 1].max() - p[:nb, 1].min())
            z = f * height / rng.uniform(*cc.height_px)
            x = rng.uniform(-1.0, 1.0) * z * (w / 2) / f
            t = np.array([x, hc - p[:nb, 1].max(), z])
            pc = (p + t) @ pitch.T
            verts.append(pc)
            faces.append(fc + off)
            alb.append(a), spec.append(s), shin.append(sh)
            ids.append(np.full(len(v), j, np.int32))
            pts = (out.points[0].numpy() @ camera.HALF_TURN_X.T + t) @ pitch.T
            people.append((pc, fc, nb, pts, shape[0].numpy()))
            off += len(v)
        v_all, f_all = np.concatenate(verts), np.concatenate(faces)
        light = look.lights(rng)
        bg = self.background(rng, w, h)
        colours = look.shade(v_all, vertex_normals(v_all, f_all), np.concatenate(alb), np.concatenate(spec),
                             np.concatenate(shin), light)
        ids_all = np.concatenate(ids)
        rgb2, lab2, _ = self.raster.set_size(2 * w, 2 * h).render(v_all, f_all, double_k(k), colours, ids_all,
                                                                  flat=False)
        img = look.composite2(rgb2, lab2 >= 0, bg)
        lab = self.raster.set_size(w, h).render(v_all, f_all, k, None, ids_all)[1]
        img, quality = look.camera_effects(rng, img)
        data = look.jpeg(img, quality)
        pts2d = np.zeros((MAX_PEOPLE, 42, 2), np.float32)
        boxes = np.zeros((MAX_PEOPLE, 4), np.float32)
        heights, visible = np.zeros(MAX_PEOPLE, np.float32), np.zeros(MAX_PEOPLE, np.float32)
        shapes = np.zeros((MAX_PEOPLE, len(self.body.shape_names)), np.float32)
        for j, (vp, fp, nb, pts, shp) in enumerate(people):
            full = self.raster.set_size(w, h).render(vp, fp, k, None, None)[1] >= 0
            uv = camera.project(vp[:nb], k)
            lo, hi = uv.min(0), uv.max(0)
            pts2d[j] = camera.project(pts, k)
            boxes[j] = [*np.clip(lo, 0, [w, h]), *np.clip(hi, 0, [w, h])]
            heights[j] = hi[1] - lo[1]
            visible[j] = (lab == j).sum() / max(full.sum(), 1)
            shapes[j] = shp
        return {"rgb": look.unjpeg(data), "rgb_jpg": data, "ids": np.where(lab >= 0, lab + 1, 0).astype(np.uint8),
                "K": k.astype(np.float32), "n_people": np.int64(n), "points2d": pts2d, "boxes": boxes,
                "heights": heights, "visible": visible, "shape": shapes, "info": np.array([quality], np.float32)}
