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

import logging
import time
from dataclasses import asdict, dataclass, field, replace
from typing import Literal, get_args

import numpy as np
import roma
import torch

from recon import camera
from recon.body import default_body, skeleton
from recon.body.base import BodyModel
from recon.errors import ReconError
from recon.fit import FitConfig, fit_body
from recon.keypoints import Keypoints, make_source
from recon.people import models as people_models
from recon.people.mediapipe import DEFAULT_MODEL, LandmarkModel, available, resolve_model
from recon.shape import FROM_MASK, PHENOTYPES, ShapeHead
from recon.smplr import SMPLR
from recon.smplr.lifter import Lifter

log = logging.getLogger(__name__)
_WARNED: set[str] = set()  # missing models already reported: one line per process

Lift = Literal["camera", "source", "blend"]
Gender = Literal["auto", "female", "male", "neutral"]
LIFTS = get_args(Lift)
GENDERS = {"female": 1.0, "male": 0.0, "neutral": 0.5}  # anny's gender phenotype; "auto": read from the image


class NoPersonFound(ReconError):
    """The keypoint source found nobody in the image."""


@dataclass
class FoundPeople:
    """The keypoint stage's answer for one image: its intrinsics and the people found, largest first."""

    k: np.ndarray  # (3, 3)
    people: list[Keypoints]
    ms_per_person: float  # the source's time


@dataclass
class Reconstruction:
    """One person in one image. Positions: OpenCV camera frame, metres; 2D: pixels."""

    image_size: tuple[int, int]  # (H, W)
    K: np.ndarray  # (3, 3)
    vertices: np.ndarray  # (V, 3)
    joints: np.ndarray  # (24, 3)
    landmarks: np.ndarray  # (18, 3)
    rotmats: np.ndarray  # (24, 3, 3) local joint rotations; root = body -> camera orientation
    shape: np.ndarray  # (S,) body-model shape parameters
    translation: np.ndarray  # (3,) pelvis position
    keypoints: Keypoints
    shape_names: tuple[str, ...] = ()
    timings_ms: dict = field(default_factory=dict)
    fit: dict = field(default_factory=dict)  # the fit after SMPLR: steps, silhouette weight used
    # how sure the gender is: |2 p - 1| of the shape head's probability p of female (0: it cannot
    # tell, and the gender is near 0.5; 1: certain, or given by the user); None without a head
    shape_confidence: float | None = None
    height_m: float | None = None  # standing height of the body shape (its rest mesh's vertical extent)

    def project(self, x: np.ndarray) -> np.ndarray:
        return camera.project(x, self.K)

    @property
    def reprojection_error_px(self) -> float:
        """Mean distance between the model's projected J+ and the detected 2D J+ inside the image."""
        pts = np.concatenate([self.joints, self.landmarks])
        inside = camera.inside_image(self.keypoints.points2d, self.image_size)
        err = np.linalg.norm(self.project(pts) - self.keypoints.points2d, axis=1)
        return float(err[inside].mean()) if inside.any() else float(err.mean())

    def to_json(self) -> dict:
        rv = roma.rotmat_to_rotvec(torch.from_numpy(self.rotmats)).numpy()
        r = lambda a, d=5: np.round(np.asarray(a, float), d).tolist()  # noqa: E731
        return {
            "frame": "OpenCV camera: x right, y down, z forward; metres; 2D in pixels",
            "image_size": list(self.image_size),
            "camera": {"K": r(self.K, 3)},
            "confidence": round(self.keypoints.confidence, 4),
            "person_score": None if self.keypoints.person_score is None else round(self.keypoints.person_score, 3),
            "found_by": self.keypoints.found_by,
            "box": r(self.keypoints.box, 1),
            "reprojection_error_px": round(self.reprojection_error_px, 2),
            "joint_names": list(skeleton.JOINT_NAMES),
            "landmark_names": list(skeleton.LANDMARK_NAMES),
            "joints3d": r(self.joints),
            "landmarks3d": r(self.landmarks),
            "joints2d": r(self.project(self.joints), 2),
            "landmarks2d": r(self.project(self.landmarks), 2),
            "keypoints2d_detected": r(self.keypoints.points2d, 2),
            "pose_axis_angle": r(rv),
            "shape": dict(zip(self.shape_names or [f"s{i}" for i in range(len(self.shape))], r(self.shape, 4),
                              strict=True)),
            "shape_confidence": None if self.shape_confidence is None else round(self.shape_confidence, 3),
            "height_m": None if self.height_m is None else round(self.height_m, 3),
            "translation": r(self.translation),
            "timings_ms": {k: round(v, 2) for k, v in self.timings_ms.items()},
            "fit": self.fit,
        }


@dataclass
class ReconstructorConfig:
    """How ``Reconstructor`` turns an image into bodies; the defaults are ``recon run``'s.

    source: keypoint source, "mediapipe" or "backbone". focal_factor: focal length in units of the
    longer image side when K is not given. device: torch device of SMPLR and the body model.
    fit: the fit after SMPLR (``FitConfig(steps=0)``: none). flip: test-time mirror averaging of
    the source (None: the source's default). lift: where SMPLR's 3D J+ come from, "camera" (the
    camera-aware lifter on the 2D and K), "source" (the source's own 3D) or "blend" (their mean);
    the fit's 3D prior follows the same points. denoise: SMPLR's 3D DAE on the J+ first.
    retry: MediaPipe asks again on other views when it finds nobody (more people found, more
    phantoms on person-free images). guard: MediaPipe's answers scored as phantoms are refused.
    detect: find people with the people stage's detector (``recon.people``: NanoDet over the image
    and zoomed tiles) and read each with the landmark model on its box; MediaPipe's own detector
    and the search below only where it finds nobody. movenet: with ``detect``, the weight of MoveNet
    Thunder's 2D keypoints fused into MediaPipe's on each box (``recon.keypoints.movenet``; 0: none).
    multipose: with ``detect``, MoveNet MultiPose's boxes as well where NanoDet's give nobody or more
    than one person is wanted (``recon.people.multipose``: people NanoDet misses or boxes as one).
    search: where MediaPipe's detector (and its retries) finds nobody, look for a person without a
    face (``recon.people.search``: back views, people cut by a border, small people).
    keypoint_model: MediaPipe's landmark model, "lite", "full" or "heavy" (its own adapter and guard;
    "full" when the file asked for is not installed). fallback: where MediaPipe finds nobody, our
    backbone answers when it is confident; backbone_weight: the weight of our backbone's J+ on
    MediaPipe's person where it is confident (0: MediaPipe's alone; both ``MediaPipeSource``: on
    photos the backbone is not confident, so neither happens there).
    shape_head: the phenotypes ``recon.shape.FROM_MASK`` (gender, build) read from the person's mask
    by ``recon.shape.ShapeHead`` instead of SMPLR's guess from the J+ (a source with masks and
    anny-like phenotypes only).
    gender: "auto" (read from the image by the shape head, else SMPLR's guess), or "female", "male",
    "neutral" (anny's gender 1, 0, 0.5) for users who know. height_cm: the person's standing
    height when known: anny's height phenotype is set to give it (with the camera's focal length
    it also fixes the distance; a single photo cannot tell scale on its own).
    smplr_path / lifter_path / shape_head_path: other weights than the shipped ones.
    """

    source: str = "mediapipe"
    focal_factor: float = 1.0
    device: str = "cpu"
    fit: FitConfig = field(default_factory=FitConfig)
    flip: bool | None = None
    lift: Lift = "blend"
    denoise: bool = True
    retry: bool = True
    guard: bool = True
    keypoint_model: LandmarkModel = DEFAULT_MODEL
    fallback: bool = False
    backbone_weight: float = 0.0
    search: bool = True
    detect: bool = True
    movenet: float = 1.0
    multipose: bool = True
    shape_head: bool = True
    gender: Gender = "auto"
    height_cm: float | None = None
    smplr_path: str | None = None
    lifter_path: str | None = None
    shape_head_path: str | None = None

    def __post_init__(self):
        """The options with a fixed set of values, checked once: every command and the API meet one check."""
        for name, allowed in (("lift", LIFTS), ("keypoint_model", get_args(LandmarkModel)),
                              ("gender", get_args(Gender))):
            if getattr(self, name) not in allowed:
                raise ReconError(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")
        if self.height_cm is not None and not 50 <= self.height_cm <= 250:
            raise ReconError(f"height_cm must lie between 50 and 250, got {self.height_cm}")

    def as_installed(self) -> ReconstructorConfig:
        """This config with the MediaPipe landmark model that will run ("full" when the one asked for
        is not installed) and ``detect`` off when the detector is not installed, so that a result
        records what it was made from."""
        if self.source != "mediapipe" or not available():
            return self
        detect = self.detect and people_models.available("nanodet")
        movenet = self.movenet if people_models.available("movenet-thunder") else 0.0
        multipose = self.multipose and detect and people_models.available("movenet-multipose")
        if self.detect and not detect and "nanodet" not in _WARNED:
            _WARNED.add("nanodet")
            log.warning("the person detector is not installed (scripts/setup.sh adds it): MediaPipe's own detector "
                        "finds one person at a time")
        return replace(self, keypoint_model=resolve_model(self.keypoint_model), detect=detect, movenet=movenet,
                       multipose=multipose)

    def to_json(self) -> dict:
        """What changes the result (not the device), for the record of what a result was made from."""
        return {k: v for k, v in asdict(self).items() if k != "device"}


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
