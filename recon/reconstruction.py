"""What the image pipeline (``recon.pipeline.Reconstructor``) takes and gives: its settings
(``ReconstructorConfig``, recon run's defaults), the people found in an image (``FoundPeople``),
one person's reconstruction (``Reconstruction``) and ``NoPersonFound``."""
from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field, replace
from typing import Literal, get_args

import numpy as np
import roma
import torch

from recon import camera
from recon.body import skeleton
from recon.errors import ReconError
from recon.fit import FitConfig
from recon.keypoints import Keypoints
from recon.people import models as people_models
from recon.people.mediapipe import DEFAULT_MODEL, LandmarkModel, available, resolve_model

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
