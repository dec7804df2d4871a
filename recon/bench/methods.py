"""Methods evaluated on the synthetic benchmarks. Each gets the RGB image and the camera
intrinsics K (as in the thesis protocol) and returns a ``Prediction`` in the camera frame.
``detects``: a discrete decision (MediaPipe's person detector, the backbone's crop search) lies
between the image and our networks, so that last-bit differences between CPUs can change the
result by more than float noise (``recon.bench.runner.check`` leaves those methods out)."""
from __future__ import annotations

import ast
import dataclasses
import re
from dataclasses import dataclass, replace

import numpy as np
import roma
import torch

from recon import camera
from recon.backbone.crop import Crop
from recon.body import skeleton
from recon.body.base import BodyModel
from recon.errors import ReconError
from recon.fit import FitConfig, fit_body
from recon.keypoints import BackboneSource, Keypoints, MediaPipePose
from recon.pipeline import Reconstructor
from recon.poses.mocap import MocapPoses
from recon.reconstruction import ReconstructorConfig
from recon.smplr import SMPLR
from recon.smplr.lifter import Lifter


@dataclass
class Prediction:
    joints: np.ndarray  # (24, 3) camera frame (only root-relative errors use it when placed=False)
    landmarks: np.ndarray | None = None  # (18, 3)
    vertices: np.ndarray | None = None  # (V, 3) camera frame, placed in the image
    mask: np.ndarray | None = None  # (H, W) bool person mask, when the method gives one
    shape: np.ndarray | None = None  # (S,) body-model shape parameters, when the method regresses them
    shape_confidence: float | None = None  # how sure the method is of the shape (recon run's result.json)
    placed: bool = False  # joints are placed in the camera (their depth is a prediction)


class MeanBaseline:
    """Training-set mean pose (chordal mean per joint) and the body model's mean shape, upright
    and facing the camera, at the image centre, at the distance where a mean-height body fills
    72.5% of the image height (the generator's average)."""

    name = "mean"
    description = "mean pose + mean shape, facing the camera"
    detects = False

    def __init__(self, body: BodyModel):
        self.body = body
        rv = torch.tensor(MocapPoses.load().split("train").rotvec[::10])
        mean = roma.special_procrustes(roma.rotvec_to_rotmat(rv).sum(0))
        mean[0] = torch.tensor(camera.HALF_TURN_X, dtype=torch.float32)  # body -> camera, seen from the front
        with torch.no_grad():
            self.out = body(mean[None])
        v = self.out.vertices[0].numpy()
        self.height = float(v[:, 1].max() - v[:, 1].min())

    def __call__(self, rgb: np.ndarray, k: np.ndarray) -> Prediction:
        size = rgb.shape[0]
        t = np.array([0.0, 0.0, k[0, 0] * self.height / (0.725 * size)])
        o = self.out
        return Prediction(o.joints[0].numpy() + t, o.landmarks[0].numpy() + t, o.vertices[0].numpy() + t,
                          placed=True)


# MediaPipe Pose (33 landmarks) -> our joints; spine/collar joints are interpolated.
MP = {"nose": 0, "l_ear": 7, "r_ear": 8, "l_sh": 11, "r_sh": 12, "l_el": 13, "r_el": 14, "l_wr": 15, "r_wr": 16,
      "l_pinky": 17, "r_pinky": 18, "l_index": 19, "r_index": 20, "l_hip": 23, "r_hip": 24, "l_knee": 25,
      "r_knee": 26, "l_ankle": 27, "r_ankle": 28, "l_heel": 29, "r_heel": 30, "l_foot": 31, "r_foot": 32}


def mediapipe_to_joints(w: np.ndarray) -> np.ndarray:
    """(33, 3) MediaPipe world landmarks -> (24, 3) in our joint order."""
    g = lambda n: w[MP[n]]  # noqa: E731
    hip, sh = 0.5 * (g("l_hip") + g("r_hip")), 0.5 * (g("l_sh") + g("r_sh"))
    j = {
        "pelvis": hip, "left_hip": g("l_hip"), "right_hip": g("r_hip"),
        "spine1": hip + 0.2 * (sh - hip), "spine2": hip + 0.45 * (sh - hip), "spine3": hip + 0.7 * (sh - hip),
        "left_knee": g("l_knee"), "right_knee": g("r_knee"), "left_ankle": g("l_ankle"), "right_ankle": g("r_ankle"),
        "left_foot": g("l_foot"), "right_foot": g("r_foot"), "neck": sh + 0.15 * (sh - hip),
        "left_collar": sh + 0.3 * (g("l_sh") - sh), "right_collar": sh + 0.3 * (g("r_sh") - sh),
        "head": 0.5 * (g("l_ear") + g("r_ear")), "left_shoulder": g("l_sh"), "right_shoulder": g("r_sh"),
        "left_elbow": g("l_el"), "right_elbow": g("r_el"), "left_wrist": g("l_wr"), "right_wrist": g("r_wr"),
        "left_hand": 0.5 * (g("l_pinky") + g("l_index")), "right_hand": 0.5 * (g("r_pinky") + g("r_index")),
    }
    return np.stack([j[n] for n in skeleton.JOINT_NAMES])


class MediaPipeBaseline:
    """MediaPipe Pose (0.10.21, the full landmark model): 3D world landmarks (metres, hip-centred,
    image-aligned axes = our camera axes) mapped to our joints; its segmentation mask for IoU.
    Optional extra: installed by scripts/setup.sh."""

    name = "mediapipe"
    description = "MediaPipe Pose 3D world landmarks mapped to our joints"
    detects = True

    def __init__(self, body: BodyModel | None = None):
        self.pose = MediaPipePose("full", segmentation=True)

    def __call__(self, rgb: np.ndarray, k: np.ndarray) -> Prediction | None:
        r = self.pose(rgb)
        if r is None:
            return None
        return Prediction(mediapipe_to_joints(r.world), mask=r.mask)


def _placed(b, vertices: bool = True) -> Prediction:
    """Prediction from ``SMPLR.lift_and_place`` output of one sample."""
    return Prediction(b.joints[0], b.landmarks[0], b.vertices[0] if vertices else None,
                      shape=b.shape[0].cpu().numpy(), placed=True)


class SMPLROracle2D:
    """The pipeline with a perfect keypoint source: the ground-truth 2D J+ of the image -> the
    camera-aware lifter (rays + K) -> SMPLR, placed by least-squares translation, then ``recon
    run``'s fit to those keypoints (no person mask)."""

    name = "smplr-gt2d"
    description = "oracle: GT 2D J+ -> camera-aware lifter -> SMPLR -> 30-step fit to the 2D (not an image method)"
    detects = False
    fit = FitConfig(silhouette=0.0)

    def __init__(self, body: BodyModel):
        self.body = body
        self.model = SMPLR.load(body)
        self.lifter = Lifter.load()
        self.needs_gt = True

    def __call__(self, rgb, k, points2d=None, **_) -> Prediction:
        uv = points2d.astype(np.float64)
        seen = camera.inside_image(uv, rgb.shape)
        x = self.lifter.lift(uv[None], k, seen[None])[0]
        b = self.model.lift_and_place(x, uv[None], k, weights=np.where(seen, 1.0, camera.OUTSIDE_WEIGHT)[None],
                                      denoise=False)
        if not self.fit.steps:
            return _placed(b)
        kp = Keypoints(x[0], uv, 1.0, (0.0, 0.0, float(rgb.shape[1]), float(rgb.shape[0])))
        f = fit_body(self.body, self.fit, b.rotmats[0], b.shape[0], b.translation[0], kp, k, rgb.shape)
        return Prediction(f.joints, f.landmarks, f.vertices, shape=f.shape.cpu().numpy(), placed=True)


class SMPLROracle2DOrthographic:
    """The lifting stage before the camera-aware lifter: GT 2D J+ back-projected to the depth
    where template bones match them, lifted by SMPLR's DAE-2D (trained on orthographic metric
    2D), placed by least-squares translation."""

    name = "smplr-gt2d-dae2d"
    description = "oracle: GT 2D J+ -> metric orthographic 2D -> DAE-2D -> SMPLR (before 0.3)"
    detects = False

    def __init__(self, body: BodyModel):
        self.model = SMPLR.load(body)
        self.needs_gt = True

    def __call__(self, rgb, k, points2d=None, **_) -> Prediction:
        # metric scale for the DAE-2D: the depth where template bones match the 2D bones
        depth = camera.depth_from_bones(points2d, k, self.model.template.numpy())
        xy = camera.normalized(points2d, k) * depth
        x = np.concatenate([xy, np.zeros((len(xy), 1))], 1)  # orthographic, metric
        return _placed(self.model.lift_and_place(x[None], points2d[None], k, mode="2d"))


class MediaPipeSMPLR:
    """The image pipeline (recon.Reconstructor) as 0.2 shipped it: MediaPipe Pose (full landmark
    model) -> adapter -> J+ -> DAE -> SMPLR -> mesh placed by reprojection. Uses the benchmark's K,
    like every method. Subclasses change the keypoint ``source``, the landmark model, the lifting
    and the fit after SMPLR."""

    name = "mediapipe-smplr"
    description = "recon.Reconstructor: MediaPipe, full model (+ its mirror image) -> adapter -> DAE -> SMPLR, no fit"
    detects = True

    # 0.2's pipeline, with MediaPipe's full landmark model and SMPLR's shape whatever recon run's default
    source, fit, lift, retry, guard, keypoint_model = ("mediapipe", FitConfig(steps=0, silhouette=0.0), "source",
                                                       False, False, "full")
    shape_head, fallback, backbone_weight = False, False, 0.0

    def __init__(self, body: BodyModel):
        self.rec = Reconstructor(body=body, source=self.source, fit=replace(self.fit), lift=self.lift, retry=self.retry,
                                 guard=self.guard, keypoint_model=self.keypoint_model, shape_head=self.shape_head,
                                 fallback=self.fallback, backbone_weight=self.backbone_weight)

    def __call__(self, rgb: np.ndarray, k: np.ndarray) -> Prediction | None:
        r = self.rec.batch([rgb], [k])[0]
        if isinstance(r, Exception):
            return None
        return Prediction(r.joints, r.landmarks, r.vertices, shape=r.shape, placed=True,  # IoU from our mesh
                          shape_confidence=r.shape_confidence)


class MediaPipeSMPLRFitKeypoints(MediaPipeSMPLR):
    name = "mediapipe-smplr-fit-kp"
    description = "recon.Reconstructor + 30-step fit to the keypoints only (`recon run --silhouette 0`)"
    fit = FitConfig(silhouette=0.0)


class MediaPipeSMPLRFit(MediaPipeSMPLR):
    name = "mediapipe-smplr-fit"
    description = "recon.Reconstructor + 30-step fit to the keypoints and MediaPipe's person mask (0.2's `recon run`)"
    fit = FitConfig()


class ReconRun(MediaPipeSMPLR):
    """``recon run`` with its defaults, whatever they are in this version; ``overrides``: the
    ``ReconstructorConfig`` fields a variant changes (``RECON_RUN_VARIANTS``)."""

    name = "recon-run"
    description = "`recon run` defaults: recon.Reconstructor()"
    overrides: dict = {}

    def __init__(self, body: BodyModel):
        self.rec = Reconstructor(body=body, **self.overrides)


# ``recon run`` with a few options changed: name -> (ReconstructorConfig fields, description)
RECON_RUN_VARIANTS = {
    "recon-run-full": (
        {"keypoint_model": "full", "shape_head": False, "fallback": False, "backbone_weight": 0.0},
        "`recon run --keypoint-model full --no-shape-head`, no backbone (the default before 0.6)"),
    "recon-run-no-shape-head": (
        {"shape_head": False, "fallback": False, "backbone_weight": 0.0},
        "`recon run --no-shape-head --no-fallback --backbone-weight 0`: gender and build from SMPLR (the keypoints), "
        "not the mask"),
    "recon-run-mediapipe-only": (
        {"search": False, "fallback": False, "backbone_weight": 0.0},
        "`recon run --no-search`: MediaPipe's detector's people and keypoints, no backbone"),
    "recon-run-fallback-only": (
        {"search": False, "fallback": True, "backbone_weight": 0.0},
        "`recon run --no-search --fallback --backbone-weight 0`: MediaPipe's keypoints alone, the backbone where it "
        "finds nobody"),
    "recon-run-0.11": (
        {"search": False, "fallback": True, "backbone_weight": 0.5},
        "`recon run` of 0.11.0: `--no-search --fallback --backbone-weight 0.5`"),
}


def recon_run_variant(name: str, overrides: dict, description: str) -> type:
    """A ``ReconRun`` with ``overrides`` of ``ReconstructorConfig``'s fields."""
    return type(name, (ReconRun,), {"name": name, "description": description, "overrides": dict(overrides)})


class MediaPipeLifterFit(MediaPipeSMPLR):
    """0.3's lifting on 0.2's detections: the images 0.2 found, scored with the lifter's blend."""

    name = "mediapipe-lifter-fit"
    description = ("recon.Reconstructor without MediaPipe's retries: adapter 2D -> camera-aware lifter, blended "
                   "with the adapter's 3D -> DAE -> SMPLR -> fit (`recon run` minus the retries)")
    fit, lift = FitConfig(), "blend"


class BackboneSMPLRFit(MediaPipeSMPLR):
    """``recon run --source backbone`` as shipped: recon.Reconstructor with our hourglass as the
    keypoint source (no mask) and the 30-step fit to its keypoints."""

    name = "backbone-smplr-fit"
    description = "recon.Reconstructor: our hourglass (crop found by the network) -> DAE -> SMPLR + 30-step " \
                  "keypoint fit (`recon run --source backbone`)"
    source, fit = "backbone", FitConfig()


class BackboneMethod:
    """Our volumetric hourglass (shipped weights) and the stages on top of it (thesis Table 2.x
    rows): ``stage`` "net" = decoded J+ alone, "dae" = after the 3D DAE, "smplr" = DAE + SMPLR
    mesh placed by reprojection of the predicted 2D. ``crop`` "gt" = the metric crop around the
    ground-truth mean joint (the thesis protocol; uses GT), "self" = found by the network
    itself (``recon.backbone.search``; no GT). ``flip``: the final prediction averaged
    with that of the mirrored crop."""

    crop, stage, flip = "gt", "net", False

    def __init__(self, body: BodyModel):
        self.source = BackboneSource(body, flip=self.flip)
        self.smplr = SMPLR.load(body) if self.stage != "net" else None
        self.needs_gt = self.crop == "gt"

    def __call__(self, rgb, k, points3d=None, **_) -> Prediction | None:
        if self.crop == "gt":
            crop = Crop.around(points3d[:24].astype(np.float64).mean(0), k)
            pts, uv, _conf = self.source.search.net.predict([rgb], [crop], flip=self.flip)
            pts, uv = pts[0], uv[0]
        else:
            kp = self.source(rgb, k)
            if kp is None:
                return None
            uv = kp.points2d
            pts = kp.points3d + camera.place(kp.points3d, uv, k)
        if self.stage == "net":
            return Prediction(pts[:24], pts[24:])
        b = self.smplr.lift_and_place(pts[None], uv[None], k, weights=camera.in_image_weights(uv, rgb.shape)[None],
                                      points_only=self.stage == "dae")
        if self.stage == "dae":
            p = b.points_in[0] + pts[:1]
            return Prediction(p[:24], p[24:])
        return _placed(b)


def _backbone(crop: str, stage: str, flip: bool = False) -> type:
    what = {"net": "J+ decoded from the volumes", "dae": "+ 3D DAE", "smplr": "+ DAE + SMPLR mesh"}[stage]
    where = {"gt": "GT metric crop (thesis protocol)", "self": "crop found by the network (no GT)"}[crop]
    name = ("backbone" + ("-gtcrop" if crop == "gt" else "") + ("" if stage == "net" else "-" + stage)
            + ("-flip" if flip else ""))
    how = ", final pass averaged with the mirrored crop" if flip else ""
    return type(name, (BackboneMethod,), {"name": name, "crop": crop, "stage": stage, "flip": flip,
                                          "detects": crop == "self",
                                          "description": f"our hourglass{how}, {where}: {what}"})


METHODS = {"mean": MeanBaseline, "mediapipe": MediaPipeBaseline, "smplr-gt2d": SMPLROracle2D,
           "smplr-gt2d-dae2d": SMPLROracle2DOrthographic, "recon-run": ReconRun,
           **{name: recon_run_variant(name, *v) for name, v in RECON_RUN_VARIANTS.items()},
           "mediapipe-lifter-fit": MediaPipeLifterFit, "mediapipe-smplr": MediaPipeSMPLR,
           "mediapipe-smplr-fit-kp": MediaPipeSMPLRFitKeypoints,
           "mediapipe-smplr-fit": MediaPipeSMPLRFit, "backbone-smplr-fit": BackboneSMPLRFit}
METHODS.update({c.name: c for c in (_backbone(crop, stage, flip) for flip in (False, True) for crop in ("gt", "self")
                                     for stage in ("net", "dae", "smplr"))})


def get_method(name: str) -> type:
    """A method class by name; ``recon-run[key=value,...]`` is ``recon run`` with those
    ``ReconstructorConfig`` fields changed (``fit_steps=N``: the fit's steps), for choices made on
    a validation benchmark (e.g. ``recon-run[backbone_weight=0.0,fallback=False]``)."""
    if name in METHODS:
        return METHODS[name]
    m = re.fullmatch(r"recon-run\[(.*)\]", name)
    if not m:
        raise ReconError(f"unknown method {name!r}; known: {', '.join(METHODS)}, recon-run[field=value,...]")
    overrides = {}
    for item in filter(None, m.group(1).split(",")):
        key, _, value = item.partition("=")
        overrides[key.strip()] = ast.literal_eval(value.strip())
    steps = overrides.pop("fit_steps", None)
    fields = {f.name for f in dataclasses.fields(ReconstructorConfig)}
    if set(overrides) - fields:
        raise ReconError(f"{name}: no ReconstructorConfig field(s) {sorted(set(overrides) - fields)}")
    if steps is not None:
        overrides["fit"] = replace(ReconstructorConfig().fit, steps=steps)
    return recon_run_variant(name, overrides, f"`recon run` with {m.group(1)}")
