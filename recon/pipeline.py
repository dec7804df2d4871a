"""Image -> 3D body: ``recon.Reconstructor``.

    rgb --keypoint source--> J+ 2D (+ the source's own 3D guess)
        --camera-aware lifter (``recon.smplr.lifter``: 2D rays + K -> 3D J+)--> [DAE] --> SMPLR (Omega, Psi)
        [gender and build from the person mask instead of Psi's: ``recon.shape.ShapeHead``]
        --> body mesh placed in the camera by least-squares reprojection onto the 2D J+ (``SMPLR.lift_and_place``)
        --> fitted to the 2D J+ and the person mask (``recon.fit``)

Keypoint sources (``recon.keypoints``): MediaPipe Pose + the learned adapter (default) or our
volumetric hourglass. Output frame: OpenCV camera (x right, y down, z forward), metres
(``recon.camera``). Intrinsics: given, or a pinhole with focal = ``focal_factor`` x the longer
image side, principal point at the centre.
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import torch

from recon import camera
from recon.body import default_body
from recon.body.base import BodyModel
from recon.fit import FitConfig, fit_body
from recon.keypoints import Keypoints, make_source
from recon.reconstruction import (
    GENDERS,
    FoundPeople,
    NoPersonFound,
    Reconstruction,
    ReconstructorConfig,
)
from recon.shape import FROM_MASK, PHENOTYPES, ShapeHead
from recon.smplr import SMPLR
from recon.smplr.lifter import Lifter


class Reconstructor:
    """``Reconstructor()(rgb) -> Reconstruction`` (raises NoPersonFound), configured by a
    ``ReconstructorConfig`` and/or its fields as keywords (``Reconstructor(source="backbone")``).
    ``body``: the body model (default anny); ``source`` may also be a ``KeypointSource`` object."""

    def __init__(self, config: ReconstructorConfig | None = None, body: BodyModel | None = None, **overrides):
        source = overrides.pop("source", None)
        if source is not None and not isinstance(source, str):
            overrides["source"] = getattr(source, "name", type(source).__name__)
            if hasattr(source, "model"):  # a MediaPipeSource: the landmark model it runs
                overrides["keypoint_model"] = source.model
        elif source is not None:
            overrides["source"] = source
        cfg = replace(config or ReconstructorConfig(), **overrides)  # checked in ReconstructorConfig.__post_init__
        self.config = cfg.as_installed()
        self.body = body or default_body()
        self.device = torch.device(cfg.device)
        self.smplr = SMPLR.load(self.body, cfg.smplr_path).to(self.device)
        self.lifter = Lifter.load(cfg.lifter_path) if cfg.lift != "source" else None
        names = tuple(getattr(self.body, "shape_names", ()))
        self.shape_head = ShapeHead.load(cfg.shape_head_path).to(self.device) \
            if cfg.shape_head and names == PHENOTYPES else None
        self.phenotypes_from_mask = FROM_MASK  # what the head gives; the rest stays SMPLR's
        self.source = (source if source is not None and not isinstance(source, str)
                       else make_source(cfg.source, self.body, cfg.device, cfg.flip, cfg.retry, cfg.guard,
                                   self.config.keypoint_model, cfg.fallback, cfg.backbone_weight, cfg.search,
                                   self.config.detect, self.config.movenet, self.config.multipose))

    @property
    def fit(self) -> FitConfig:
        return self.config.fit

    @fit.setter
    def fit(self, value: FitConfig) -> None:
        self.config = replace(self.config, fit=value)

    @property
    def focal_factor(self) -> float:
        return self.config.focal_factor

    @property
    def lift(self) -> str:
        return self.config.lift

    @property
    def denoise(self) -> bool:
        return self.config.denoise

    @property
    def faces(self) -> np.ndarray:
        return self.body.faces.cpu().numpy()

    def __call__(self, rgb: np.ndarray, k: np.ndarray | None = None) -> Reconstruction:
        out = self.batch([rgb], [k])[0]
        if isinstance(out, Exception):
            raise out
        return out

    def batch(self, images: list[np.ndarray], ks: list[np.ndarray | None] | None = None
              ) -> list[Reconstruction | Exception]:
        """Keypoints per image, then one batched SMPLR + body call for all found people.
        Entries are Reconstructions, or NoPersonFound for images without a person."""
        return [r if isinstance(r, Exception) else r[0] for r in self.people(images, ks, 1)]

    def people(self, images: list[np.ndarray], ks: list[np.ndarray | None] | None = None, max_people: int = 1
               ) -> list[list[Reconstruction] | Exception]:
        """Up to ``max_people`` people per image (a source without ``people()`` finds one), the
        largest first. Entries are lists of Reconstructions, or NoPersonFound."""
        return self.people_from(images, self.find_people(images, ks, max_people))

    def find_people(self, images: list[np.ndarray], ks: list[np.ndarray | None] | None = None, max_people: int = 1
                    ) -> list[FoundPeople]:
        """The keypoint stage of ``people`` (the source's calls, in order: a video source follows
        the frames); ``people_from`` does the rest. Split so that a video can run the two stages
        of consecutive frames at once."""
        if max_people < 1:
            raise ValueError("max_people must be at least 1")
        ks = ks or [None] * len(images)
        out = []
        for rgb, k in zip(images, ks, strict=True):
            _check_image(rgb)
            k = camera.default_intrinsics(*rgb.shape[:2], self.focal_factor) if k is None else np.asarray(k, float)
            t0 = time.perf_counter()
            if max_people > 1 and hasattr(self.source, "people"):
                people = self.source.people(rgb, k, max_people)
            else:
                people = [kp] if (kp := self.source(rgb, k)) is not None else []
            people.sort(key=lambda kp: -(kp.box[2] - kp.box[0]) * (kp.box[3] - kp.box[1]))
            out.append(FoundPeople(k, people, (time.perf_counter() - t0) * 1000 / max(len(people), 1)))
        return out

    def people_from(self, images: list[np.ndarray], found_people: list[FoundPeople]
                    ) -> list[list[Reconstruction] | Exception]:
        """``people`` from the keypoint stage's answers (``find_people``) for the same images."""
        if len(found_people) != len(images):
            raise ValueError(f"{len(found_people)} keypoint answers for {len(images)} images")
        results: list = [None] * len(images)
        found, kps, kmats, t_kp = [], [], [], {}
        for i, f in enumerate(found_people):
            t_kp[i] = f.ms_per_person
            if not f.people:
                results[i] = NoPersonFound("no person found")
                continue
            results[i] = []
            for kp in f.people:
                found.append(i)
                kps.append(kp)
                kmats.append(f.k)
        if not found:
            return results
        t0 = time.perf_counter()
        uv, kk = np.stack([kp.points2d for kp in kps]), np.stack(kmats)
        seen = np.stack([camera.inside_image(kp.points2d, images[i].shape) for i, kp in zip(found, kps, strict=True)])
        points = np.stack([kp.points3d for kp in kps])
        if self.lifter is not None:
            lifted = self.lifter.lift(uv, kk, seen)[0]
            points = lifted if self.lift == "camera" else 0.5 * (lifted + points)
            kps = [replace(kp, points3d=p - p[:1]) for kp, p in zip(kps, points, strict=True)]
        t1 = time.perf_counter()
        known_shape, confidence = self._shape_from_masks(kps)
        known_shape = self._given_shape(known_shape, len(kps))
        t_shape = (time.perf_counter() - t1) * 1000 / len(found)
        weights = np.where(seen, 1.0, camera.OUTSIDE_WEIGHT)
        placed = self.smplr.lift_and_place(points, uv, kk, weights=weights, denoise=self.denoise, shape=known_shape)
        if self.config.height_cm is not None:  # SMPLR's other phenotypes at the given height, placed again
            known_shape = self._with_height(placed.shape.cpu().numpy(), known_shape)
            placed = self.smplr.lift_and_place(points, uv, kk, weights=weights, denoise=self.denoise,
                                               shape=known_shape)
        t_smplr = (time.perf_counter() - t0) * 1000 / len(found) - t_shape
        for n, i in enumerate(found):
            kp, k = kps[n], kmats[n]
            timings = {"keypoints": t_kp[i], "smplr": t_smplr}
            if known_shape is not None:
                timings["shape"] = t_shape
            rot, shape, t = placed.rotmats[n], placed.shape[n], placed.translation[n]
            v, j, lm = placed.vertices[n], placed.joints[n], placed.landmarks[n]
            silhouette = 0.0
            if self.fit.steps:
                t1 = time.perf_counter()
                f = fit_body(self.body, self.fit, rot, shape, t, kp, k, images[i].shape, self.device, self._fixed)
                rot, shape, t, v, j, lm = f.rotmats, f.shape, f.translation, f.vertices, f.joints, f.landmarks
                silhouette = f.silhouette
                timings["refine"] = (time.perf_counter() - t1) * 1000
            results[i].append(Reconstruction(
                image_size=tuple(images[i].shape[:2]), K=k, vertices=v, joints=j, landmarks=lm,
                rotmats=rot.cpu().numpy(), shape=shape.cpu().numpy(), translation=t, keypoints=kp,
                shape_names=tuple(getattr(self.body, "shape_names", ())), timings_ms=timings,
                fit={"steps": self.fit.steps, "silhouette": silhouette},
                shape_confidence=1.0 if self.config.gender != "auto" else confidence[n],
                height_m=self.standing_height(shape)))
        return results

    def _shape_from_masks(self, kps: list[Keypoints]) -> tuple[np.ndarray | None, list[float | None]]:
        """(B, S) phenotypes ``phenotypes_from_mask`` read by the shape head from each person's mask,
        NaN elsewhere (SMPLR keeps its own), or None without a head or masks; and each person's
        gender confidence (|2 p - 1|; None without a mask)."""
        confidence: list[float | None] = [None] * len(kps)
        with_mask = [n for n, kp in enumerate(kps) if kp.mask is not None]
        if self.shape_head is None or not with_mask:
            return None, confidence
        pred = self.shape_head.predict([kps[n].mask for n in with_mask], [kps[n].points2d for n in with_mask])
        cols = [PHENOTYPES.index(p) for p in self.phenotypes_from_mask]
        shape = np.full((len(kps), len(PHENOTYPES)), np.nan)
        shape[np.ix_(with_mask, cols)] = pred[:, cols]
        for n, p in zip(with_mask, pred[:, PHENOTYPES.index("gender")], strict=True):
            confidence[n] = float(abs(2.0 * p - 1.0))
        return shape, confidence

    def standing_height(self, shape: torch.Tensor) -> float:
        """A body shape's standing height (m)."""
        return float(self.standing_heights(shape.reshape(1, -1))[0])

    def standing_heights(self, shapes) -> np.ndarray:
        """(B,) standing heights (m) of body shapes (B, S): their rest meshes' vertical extents."""
        with torch.no_grad():
            v = self.body.rest_geometry(torch.as_tensor(shapes).to(self.body.mean_shape))[0]
        return (v[..., 1].amax(1) - v[..., 1].amin(1)).cpu().numpy()

    @property
    def _fixed(self) -> np.ndarray | None:
        """(S,) the phenotypes the user gave (gender, height), which the fit keeps."""
        names = list(getattr(self.body, "shape_names", ()))
        fixed = np.array([(n == "gender" and self.config.gender != "auto")
                          or (n == "height" and self.config.height_cm is not None) for n in names])
        return fixed if fixed.any() else None

    def _given_shape(self, known: np.ndarray | None, b: int) -> np.ndarray | None:
        """``known`` with the gender the user gave (``config.gender``)."""
        names = list(getattr(self.body, "shape_names", ()))
        if self.config.gender == "auto" or "gender" not in names:
            return known
        known = np.full((b, len(names)), np.nan) if known is None else known.copy()
        known[:, names.index("gender")] = GENDERS[self.config.gender]
        return known

    def _with_height(self, shape: np.ndarray, known: np.ndarray | None) -> np.ndarray:
        """``known`` with anny's height phenotype set so that each body (its other phenotypes:
        ``shape`` (B, S)) stands ``config.height_cm`` tall (the nearest reachable height)."""
        names = list(self.body.shape_names)
        h = names.index("height")
        known = np.full_like(shape, np.nan) if known is None else known.copy()
        grid = np.linspace(0.0, 1.0, 21)
        for n, s in enumerate(shape):
            trial = np.repeat(np.where(np.isnan(known[n]), s, known[n])[None], len(grid), 0)
            trial[:, h] = grid
            heights = self.standing_heights(trial) * 100.0
            known[n, h] = float(np.interp(self.config.height_cm, heights, grid))  # heights grow with it
        return known

    def posed_body(self, rec: Reconstruction):
        """Re-run the body model from the reconstruction's parameters (camera frame)."""
        rot = torch.tensor(rec.rotmats, dtype=torch.float32)[None]
        shape = torch.tensor(rec.shape, dtype=torch.float32)[None]
        with torch.no_grad():
            return self.body(rot, shape, transl=torch.tensor(rec.translation, dtype=torch.float32)[None])


def _check_image(rgb) -> None:
    if not isinstance(rgb, np.ndarray) or rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError("expected an (H, W, 3) uint8 RGB array (use recon.io.load_image for files)")
