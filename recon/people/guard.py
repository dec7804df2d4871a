"""Is a MediaPipe answer a person? Evidence and the rule that rejects phantom bodies.

MediaPipe Pose always proposes a full skeleton, even on a horse, a logo or a chessboard. The
evidence of one answer: its visibilities, its box, the support of its own person mask under the
landmarks, and whether its metric 3D landmarks (``world``) form a human body that projects onto
its 2D landmarks. The rule and its thresholds were chosen on synth-val people against
person-free images of the generator's background sampler (eval/phantoms.py,
eval/results/phantoms.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from recon.people.mediapipe import MPPose

# MediaPipe Pose landmark indices
L_SHOULDER, R_SHOULDER, L_ELBOW, R_ELBOW, L_WRIST, R_WRIST = 11, 12, 13, 14, 15, 16
L_HIP, R_HIP, L_KNEE, R_KNEE, L_ANKLE, R_ANKLE = 23, 24, 25, 26, 27, 28
LIMBS = ((L_SHOULDER, L_ELBOW, R_SHOULDER, R_ELBOW), (L_ELBOW, L_WRIST, R_ELBOW, R_WRIST),
         (L_HIP, L_KNEE, R_HIP, R_KNEE), (L_KNEE, L_ANKLE, R_KNEE, R_ANKLE))
CORE_PLUS_NOSE = (0, L_SHOULDER, R_SHOULDER, L_HIP, R_HIP)
NEUTRAL_ASYM = 0.06  # the people's median, for answers with no limb seen on both sides


def _length(p: np.ndarray, a: int, b: int) -> float:
    return float(np.linalg.norm(p[a] - p[b]))


def evidence(r: MPPose, image_shape) -> dict[str, float]:
    """Numbers describing one MediaPipe answer (see the module docstring). Only landmarks inside
    the image count for visibility and geometry: a portrait's legs are guesses, not evidence."""
    h, w = image_shape[:2]
    vis, xy, world = r.visibility, r.image_xy, r.world
    inside = (xy[:, 0] >= 0) & (xy[:, 0] < w) & (xy[:, 1] >= 0) & (xy[:, 1] < h)
    seen = inside & (vis > 0.5)
    pts = xy[seen] if seen.sum() >= 4 else xy[inside] if inside.sum() >= 4 else xy
    lo, hi = pts.min(0), pts.max(0)
    size = float(max(hi[0] - lo[0], hi[1] - lo[1], 1.0))
    core = [k for k in CORE_PLUS_NOSE if inside[k]]
    limbs = [(a, b, c, d) for a, b, c, d in LIMBS if seen[[a, b, c, d]].all()]
    asym = float(np.mean([abs(_length(world, a, b) - _length(world, c, d))
                          / max(_length(world, a, b) + _length(world, c, d), 1e-6) for a, b, c, d in limbs])
                 ) if limbs else NEUTRAL_ASYM
    # 2D-3D agreement of the seen landmarks: the world landmarks (camera-aligned axes) projected
    # orthographically, scaled and shifted onto the image ones; residual as a fraction of the box
    use = seen if seen.sum() >= 4 else np.ones(len(xy), bool)
    a0, b0 = world[use, :2] - world[use, :2].mean(0), xy[use] - xy[use].mean(0)
    s = float((a0 * b0).sum() / max((a0 ** 2).sum(), 1e-12))
    proj = float(np.sqrt(((s * a0 - b0) ** 2).sum(1).mean()) / size)
    # torso tilt: mid-shoulder minus mid-hip against the image's up, in degrees (0: upright)
    up = 0.5 * (xy[L_SHOULDER] + xy[R_SHOULDER]) - 0.5 * (xy[L_HIP] + xy[R_HIP])
    tilt = float(np.degrees(np.arctan2(abs(up[0]), -up[1])))
    ev = {"conf": float(vis[inside].mean()) if inside.any() else 0.0, "tilt": tilt,
          "inside": float(inside.mean()),
          "conf_core": float(vis[core].mean()) if core else 0.0, "box_frac": float((hi[1] - lo[1]) / h),
          "box_px": size, "aspect": float((hi[0] - lo[0]) / max(hi[1] - lo[1], 1.0)), "asym": asym,
          "proj": proj, "seen": float(seen.mean()), "mask_box": -1.0, "mask_lm": -1.0}
    if r.mask is not None:
        m = r.mask
        x0, y0 = np.clip(np.floor(lo).astype(int), 0, [w - 1, h - 1])
        x1, y1 = np.clip(np.ceil(hi).astype(int), 0, [w - 1, h - 1])
        box = m[y0:y1 + 1, x0:x1 + 1]
        ev["mask_box"] = float(box.mean()) if box.size else 0.0
        grown = cv2.dilate(m.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        q = np.round(xy[seen]).astype(int).reshape(-1, 2)
        q = q[(q[:, 0] < w) & (q[:, 1] < h)]
        ev["mask_lm"] = float(grown[q[:, 1], q[:, 0]].mean()) if len(q) else 0.0
    return ev


# No mask is no evidence either way: the people's medians stand in for it.
NO_MASK = {"mask_box": 0.47, "mask_lm": 1.0}


def features(ev: dict[str, float]) -> dict[str, float]:
    ev = ev | {k: v for k, v in NO_MASK.items() if ev.get(k, -1.0) < 0}
    return {"log_box_px": float(np.log(max(ev["box_px"], 1.0))), "box_frac": ev["box_frac"], "conf": ev["conf"],
            "conf_core": ev["conf_core"], "log_proj": float(np.log(ev["proj"] + 1e-3)), "mask_box": ev["mask_box"],
            "mask_lm": ev["mask_lm"], "log_aspect": float(np.log(max(ev["aspect"], 1e-3))), "asym": ev["asym"],
            "seen": ev["seen"], "inside": ev["inside"], "upright": float(np.cos(np.radians(ev["tilt"])))}


@dataclass(frozen=True)
class Guard:
    """A logistic score over the evidence (``features`` name -> weight, plus a bias) and its
    thresholds: a first answer needs ``image``; a retry view's answer, where phantoms come from,
    needs ``retry`` or, from ``confirmed``, MediaPipe's confirmation on a crop around it
    (``MediaPipeSource``)."""

    weights: dict[str, float]
    bias: float
    threshold: dict[str, float]

    def score(self, ev: dict[str, float]) -> float:
        """The log-odds of person of one answer's evidence."""
        return float(sum(self.weights[k] * v for k, v in features(ev).items()) + self.bias)

    def accept(self, ev: dict[str, float], retry: bool = False, confirmed: bool = False) -> bool:
        """Whether an answer's evidence says person; ``retry``: it came from a retry view,
        ``confirmed``: MediaPipe found the same person again on a crop around it."""
        s = self.score(ev)
        t = self.threshold
        return s >= t["image"] if not retry else s >= t["retry"] or (confirmed and s >= t["confirmed"])

    def describe(self) -> str:
        t = self.threshold
        return (f"a logistic score of {len(self.weights)} evidence terms: at least {t['image']:g} for MediaPipe's "
                f"first answer; for a retry view's, {t['retry']:g}, or {t['confirmed']:g} when MediaPipe "
                "finds the same person again on a crop around it")


# The score fitted by eval/phantoms.py on synth-val people (every MediaPipe answer, whole and cut to
# half-body) against the phantoms MediaPipe gives on the generator's person-free images at low
# detection thresholds; thresholds set per landmark model on its default answers there and on the
# person-free images (eval/results/phantoms[-<model>].md). lite has no guard of its own: full's.
FULL = Guard(
    weights={"log_box_px": -0.284, "box_frac": 2.624, "conf": 1.458, "conf_core": 2.551, "log_proj": -0.554,
             "mask_box": -1.364, "mask_lm": 2.477, "log_aspect": -0.296, "asym": -0.705, "seen": 1.146,
             "inside": 1.552, "upright": 0.72},
    bias=-8.271, threshold={"image": -1.0, "retry": 2.0, "confirmed": -1.0})
# heavy: full's score (a logistic fit on heavy's own answers lets more phantoms through), with a
# higher bar for retry answers, where heavy's phantoms come from
HEAVY = Guard(weights=FULL.weights, bias=FULL.bias, threshold={"image": -1.0, "retry": 2.5, "confirmed": 0.0})
GUARDS = {"full": FULL, "heavy": HEAVY}


def for_model(model: str) -> Guard:
    """The guard fitted on a landmark model's answers (full's for a model without one)."""
    return GUARDS.get(model, FULL)
