"""Image -> dressed-able 3D body: ``recon.Reconstructor``.

    rgb --keypoint source--> J+ (3D root-relative + 2D) --DAE--> SMPLR (Omega, Psi) --> body mesh
        --> placed in the camera by least-squares reprojection of J+ onto the 2D keypoints.

Keypoint sources implement ``__call__(rgb, K) -> Keypoints | None`` (None: no person found).
Shipped: ``MediaPipeSource`` (MediaPipe Pose + the learned adapter to our J+, the default) and
``BackboneSource`` (our volumetric hourglass alone, trained on synthetic renders only).

Output frame: OpenCV camera (x right, y down, z forward), metres. Intrinsics: given, or a
pinhole with focal = ``focal_factor`` x the longer image side, principal point at the centre.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from recon.body import skeleton

# SMPLR takes J+ in a viewer frame with +Y up and +Z towards the viewer (OpenGL camera axes);
# OpenCV camera axes (y down, z forward) differ by a half turn about X.
OPENCV_TO_VIEW = np.array([1.0, -1.0, -1.0])


class NoPersonFound(RuntimeError):
    pass


@dataclass
class Keypoints:
    points3d: np.ndarray  # (42, 3) J+ root-relative, metres, camera axes
    points2d: np.ndarray  # (42, 2) pixels
    confidence: float  # [0, 1]
    box: tuple[float, float, float, float]  # person box x0, y0, x1, y1 (pixels)
    mask: np.ndarray | None = None  # (H, W) bool person mask


def default_intrinsics(h: int, w: int, focal_factor: float = 1.0) -> np.ndarray:
    f = focal_factor * max(h, w)
    return np.array([[f, 0.0, w / 2.0], [0.0, f, h / 2.0], [0.0, 0.0, 1.0]])


class MediaPipeSource:
    """MediaPipe Pose landmarks -> our J+ via the learned adapter (recon.keypoints.adapter).
    ``flip``: also run on the mirrored image and average the two J+ (mirrored back, left and
    right swapped), unless the mirrored run finds nobody or someone else: ~4 mm of P1 on
    synth-val for one more MediaPipe call (~25 ms)."""

    name = "mediapipe"

    def __init__(self, adapter_path=None, flip: bool = True):
        from recon.keypoints.adapter import KeypointAdapter
        from recon.keypoints.mediapipe import MediaPipePose

        self.adapter = KeypointAdapter.load(adapter_path)
        self.mp = MediaPipePose()
        self.flip = flip

    def _detect(self, rgb: np.ndarray, k: np.ndarray):
        r = self.mp(rgb)
        return None if r is None else (r, *self.adapter.predict(r, k))

    def __call__(self, rgb: np.ndarray, k: np.ndarray) -> Keypoints | None:
        found = self._detect(rgb, k)
        if found is None:
            return None
        r, p3, uv = found
        box = r.box()
        if self.flip:
            w = rgb.shape[1]
            km = np.array(k, float)
            km[0, 2] = w - km[0, 2]  # the mirrored camera: u -> w - u
            mirrored = self._detect(np.ascontiguousarray(rgb[:, ::-1]), km)
            if mirrored is not None:
                mirror = list(skeleton.POINT_MIRROR)
                p3m = mirrored[1][mirror] * np.array([-1.0, 1.0, 1.0])
                uvm = mirrored[2][mirror]
                uvm[:, 0] = w - uvm[:, 0]
                size = max(box[2] - box[0], box[3] - box[1], 1.0)
                inside = _in_image(uv, rgb.shape) == 1.0  # guesses outside the image may disagree
                d = np.linalg.norm(uvm - uv, axis=1)[inside if inside.any() else slice(None)]
                if np.median(d) < 0.25 * size:  # the same person (another one would be far off)
                    p3, uv = 0.5 * (p3 + p3m), 0.5 * (uv + uvm)
        return Keypoints(p3, uv, float(np.mean(r.visibility)), box, r.mask)


class BackboneSource:
    """The volumetric stacked hourglass (recon.backbone) without any other detector: a first
    pass over the whole image (first hourglass only) locates the person, then ``passes - 1``
    metric crops centred on the predicted joints at the bone-length depth (bones foreshortened
    as the previous pass predicted them in 3D), the last one optionally averaged with its
    mirror image (``flip``). ``None`` when the mean peak confidence is under
    ``min_confidence`` (the network saw no person in training, so this is a weak test)."""

    name = "backbone"

    def __init__(self, body=None, weights=None, passes: int = 3, min_confidence: float = 0.05, device: str = "cpu",
                 jit: bool = True, quick_locate: bool = True, flip: bool = False):
        from recon.backbone.model import Backbone
        from recon.body import default_body
        from recon.smplr.features import template_distances

        self.net = Backbone.load(weights, device, jit)
        self.template = template_distances(body or default_body()).cpu().numpy()
        self.passes, self.min_confidence = passes, min_confidence
        self.flip = flip  # last pass averaged with its mirror image (Backbone.grids): ~2.5 mm of P1 for
        # ~30 ms (off by default: with it the pipeline misses the 100 ms latency goal on this CPU)
        self.quick_locate = quick_locate  # False: whole network in the first pass (benchmark; the
        # shipped crop factors are calibrated for the first stack)

    def locate(self, rgb: np.ndarray, k: np.ndarray, depth_scale=None, passes: int | None = None):
        """Run the passes (default ``self.passes``); returns the last pass' (J+ camera frame, 2D,
        confidences, crop)."""
        from recon.backbone.model import crop_from_keypoints, whole_image_crop

        scale = self.net.depth_scale if depth_scale is None else depth_scale
        crop = whole_image_crop(rgb.shape, k)
        passes = self.passes if passes is None else passes
        for p in range(passes):
            last = p == passes - 1
            pts, uv, conf = self.net.predict([rgb], [crop], locate=self.quick_locate and p == 0 and passes > 1,
                                             flip=self.flip and last)
            if not last:  # bone-length depth, times the factor calibrated on synth-val
                crop = crop_from_keypoints(uv[0], k, self.template, scale[min(p, len(scale) - 1)],
                                           self.depth_points(pts[0]))
        return pts[0], uv[0], conf[0], crop

    def depth_points(self, pts: np.ndarray) -> np.ndarray | None:
        """The predicted J+ that foreshorten the bones of the crop-depth estimate, or None for
        weights calibrated for plain bone lengths (recon.backbone.model.depth_from_bones)."""
        return pts if self.net.depth_method == "foreshortened" else None

    def __call__(self, rgb: np.ndarray, k: np.ndarray) -> Keypoints | None:
        pts, uv, conf, _ = self.locate(rgb, k)
        c = float(conf.mean())
        if c < self.min_confidence:
            return None
        h, w = rgb.shape[:2]
        x0, y0 = np.clip(uv.min(0), 0, [w, h])
        x1, y1 = np.clip(uv.max(0), 0, [w, h])
        return Keypoints(pts - pts[:1], uv, c, (float(x0), float(y0), float(x1), float(y1)))


def make_source(name: str, body=None, device: str = "cpu", flip: bool | None = None):
    """Keypoint source by name: "mediapipe" (default) or "backbone". ``flip`` (test-time mirror
    averaging, see each source): None = the source's default, on for MediaPipe (cheap next to
    the fit), off for the backbone (its 100 ms latency goal)."""
    if name == "mediapipe":
        return MediaPipeSource(flip=True if flip is None else flip)
    if name == "backbone":
        return BackboneSource(body, device=device, flip=bool(flip))
    raise ValueError(f"unknown keypoint source {name!r}; choose 'mediapipe' or 'backbone'")


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

    def project(self, x: np.ndarray) -> np.ndarray:
        p = x @ self.K.T
        return p[:, :2] / p[:, 2:]

    @property
    def reprojection_error_px(self) -> float:
        """Mean distance between the model's projected J+ and the detected 2D J+ inside the image."""
        pts = np.concatenate([self.joints, self.landmarks])
        inside = _in_image(self.keypoints.points2d, self.image_size) == 1.0
        err = np.linalg.norm(self.project(pts) - self.keypoints.points2d, axis=1)
        return float(err[inside].mean()) if inside.any() else float(err.mean())

    def to_json(self) -> dict:
        import roma

        rv = roma.rotmat_to_rotvec(torch.from_numpy(self.rotmats)).numpy()
        r = lambda a, d=5: np.round(np.asarray(a, float), d).tolist()  # noqa: E731
        return {
            "frame": "OpenCV camera: x right, y down, z forward; metres; 2D in pixels",
            "image_size": list(self.image_size),
            "camera": {"K": r(self.K, 3)},
            "confidence": round(self.keypoints.confidence, 4),
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
            "shape": dict(zip(self.shape_names or [f"s{i}" for i in range(len(self.shape))], r(self.shape, 4))),
            "translation": r(self.translation),
            "timings_ms": {k: round(v, 2) for k, v in self.timings_ms.items()},
            "fit": self.fit,
        }


class Reconstructor:
    """``Reconstructor()(rgb) -> Reconstruction`` (raises NoPersonFound).

    Args:
        body: body model (default anny).
        source: keypoint source object, or "mediapipe" (default) / "backbone".
        focal_factor: focal length in units of the longer image side when K is not given.
        device: torch device for SMPLR and the body model.
        refine_steps: Adam steps fitting the body to the detected keypoints after SMPLR (0: off).
        silhouette: weight of the person-mask term in that fit (sources with a mask: MediaPipe's
            segmentation), which also fits the body shape; 0 = keypoints only.
        silhouette_cover: weight of its "reach the mask's contour" half against its "stay inside
            the mask" half; < 1 because clothes, hair and hats widen a photo's mask beyond the body.
    """

    def __init__(self, body=None, source=None, focal_factor: float = 1.0, device: str = "cpu", smplr_path=None,
                 refine_steps: int = 0, silhouette: float = 10.0, shape_lr: float = 0.01, shape_prior: float = 1e-3,
                 silhouette_stride: int = 7, silhouette_cover: float = 0.3):
        from recon.body import default_body
        from recon.smplr import SMPLR

        self.body = body or default_body()
        self.device = torch.device(device)
        self.smplr = SMPLR.load(self.body, smplr_path).to(self.device)
        self.source = make_source(source or "mediapipe", self.body, device) if source is None or isinstance(source, str) \
            else source
        self.focal_factor = focal_factor
        self.refine_steps = refine_steps
        self.silhouette, self.shape_lr, self.shape_prior, self.silhouette_stride = silhouette, shape_lr, shape_prior, silhouette_stride
        self.silhouette_cover = silhouette_cover

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
        ks = ks or [None] * len(images)
        results: list = [None] * len(images)
        found, kps, kmats, t_kp = [], [], [], []
        for i, (rgb, k) in enumerate(zip(images, ks)):
            _check_image(rgb)
            k = default_intrinsics(*rgb.shape[:2], self.focal_factor) if k is None else np.asarray(k, float)
            t0 = time.perf_counter()
            kp = self.source(rgb, k)
            t_kp.append((time.perf_counter() - t0) * 1000)
            if kp is None:
                results[i] = NoPersonFound("no person found")
                continue
            found.append(i)
            kps.append(kp)
            kmats.append(k)
        if not found:
            return results
        t0 = time.perf_counter()
        x = torch.tensor(np.stack([kp.points3d for kp in kps]) * OPENCV_TO_VIEW, dtype=torch.float32,
                         device=self.device)
        with torch.no_grad():
            o = self.smplr(x, mode="3d", denoise=True)
        flip = torch.tensor(np.diag(OPENCV_TO_VIEW), dtype=torch.float32, device=self.device)
        t_smplr = (time.perf_counter() - t0) * 1000 / len(found)
        for n, i in enumerate(found):
            v = o.body.vertices[n].cpu().numpy() * OPENCV_TO_VIEW
            j = o.body.joints[n].cpu().numpy() * OPENCV_TO_VIEW
            lm = o.body.landmarks[n].cpu().numpy() * OPENCV_TO_VIEW
            pts = np.concatenate([j, lm]) - j[:1]
            t = place(pts, kps[n].points2d, kmats[n], weights=_in_image(kps[n].points2d, images[i].shape))
            rot = o.rotmats[n].clone()
            rot[0] = flip @ rot[0]  # root orientation: view frame -> OpenCV camera frame
            v, j, lm = v - j[:1] + t, j - j[:1] + t, lm - j[:1] + t  # placed in the camera
            timings = {"keypoints": t_kp[i], "smplr": t_smplr}
            shape = o.shape[n]
            fit = {"steps": self.refine_steps, "silhouette": self.mask_weight(kps[n]) if self.refine_steps else 0.0}
            if self.refine_steps:
                t1 = time.perf_counter()
                rot, shape, t, (v, j, lm) = self.refine(rot, o.shape[n], t, kps[n], kmats[n], images[i].shape)
                timings["refine"] = (time.perf_counter() - t1) * 1000
            results[i] = Reconstruction(
                image_size=tuple(images[i].shape[:2]), K=kmats[n], vertices=v, joints=j, landmarks=lm,
                rotmats=rot.cpu().numpy(), shape=shape.cpu().numpy(), translation=t, keypoints=kps[n],
                shape_names=tuple(getattr(self.body, "shape_names", ())), timings_ms=timings, fit=fit)
        return results

    def refine(self, rot: torch.Tensor, shape: torch.Tensor, t: np.ndarray, kp: Keypoints, k: np.ndarray, image_shape,
               prior: float = 0.05, depth_prior: float = 20.0):
        """Fit the body to the detected 2D J+ (inside the image) and, when the source gives a
        person mask and ``silhouette`` > 0, to the mask (``SilhouetteTarget``): Adam on
        root/joint rotation offsets, translation and (silhouette only) shape, with priors
        keeping pose and shape near SMPLR's and the 3D J+ near the detected ones (depth is what
        2D cannot fix). Returns (rotmats, shape, t, camera-frame (vertices, joints, landmarks))."""
        import roma

        dev = self.device
        w = torch.tensor(_in_image(kp.points2d, image_shape) == 1.0, dtype=torch.float32, device=dev)
        uv = torch.tensor(kp.points2d, dtype=torch.float32, device=dev)
        kk = torch.tensor(k, dtype=torch.float32, device=dev)
        p3 = torch.tensor(kp.points3d, dtype=torch.float32, device=dev)
        delta = torch.zeros(24, 3, device=dev, requires_grad=True)
        tt = torch.tensor(t, dtype=torch.float32, device=dev).requires_grad_(True)
        shape0 = shape[None].to(dev)
        dshape = torch.zeros_like(shape0, requires_grad=True)
        params = [{"params": [delta], "lr": 0.02}, {"params": [tt], "lr": 0.01}]
        sil, ids = None, None
        if self.mask_weight(kp) > 0:
            sil = SilhouetteTarget(kp.mask, kp.box, dev, cover=self.silhouette_cover)
            params.append({"params": [dshape], "lr": self.shape_lr})
            ids = torch.arange(0, self.body.num_vertices, self.silhouette_stride, device=dev)
        rest0, rest_jac = _linear_rest_geometry(self.body, shape0, ids, with_jacobian=sil is not None)
        opt = torch.optim.Adam(params)
        lo_hi = self.body.shape_range

        def project(x):
            p = x @ kk.T
            return p[..., :2] / p[..., 2:].clamp_min(1e-3)

        def shaped(d):  # shape offset inside the model's range
            return d if lo_hi is None else (shape0 + d).clamp(*lo_hi) - shape0

        for _ in range(self.refine_steps):
            r = rot.to(dev) @ roma.rotvec_to_rotmat(delta)
            rest = rest0 if rest_jac is None else tuple(x + torch.einsum("bnks,bs->bnk", jx, shaped(dshape))
                                                       for x, jx in zip(rest0, rest_jac))
            if sil is None:
                o = self.body(r[None], transl=tt[None], points_only=True, rest=rest)
                pts = o.points[0]
            else:
                o = self.body(r[None], transl=tt[None], vertex_ids=ids, rest=rest)
                pts = torch.cat([o.joints[0], o.landmarks[0]])
            e2d = (((project(pts) - uv) / kk[0, 0]) ** 2).sum(-1)
            e3d = ((pts - pts[:1]) - p3).pow(2).sum(-1)
            loss = (w * e2d).sum() / w.sum().clamp_min(1) + depth_prior * 1e-3 * e3d.mean() + prior * 1e-3 * delta.pow(2).sum()
            if sil is not None:
                loss = loss + self.silhouette * sil(project(o.vertices[0])) * (kk[0, 0] / sil.size) ** -2 \
                    + self.shape_prior * dshape.pow(2).sum()
            opt.zero_grad()
            loss.backward()
            opt.step()
        with torch.no_grad():
            r = rot.to(dev) @ roma.rotvec_to_rotmat(delta)
            shp = shape0 + shaped(dshape)
            o = self.body(r[None], shp, transl=tt[None])
        return (r.cpu(), shp[0].cpu(), tt.detach().cpu().numpy().astype(np.float64),
                tuple(x[0].cpu().numpy().astype(np.float64) for x in (o.vertices, o.joints, o.landmarks)))

    def mask_weight(self, kp: Keypoints) -> float:
        """The silhouette weight the fit uses for these keypoints: 0 without a mask, or when the
        mask covers under 10 % of the keypoints' box (a failed segmentation)."""
        if self.silhouette <= 0 or kp.mask is None:
            return 0.0
        h, w = kp.mask.shape
        x0, y0, x1, y1 = (int(round(v)) for v in kp.box)
        x0, x1, y0, y1 = max(x0, 0), min(max(x1, x0 + 1), w), max(y0, 0), min(max(y1, y0 + 1), h)
        area = max((x1 - x0) * (y1 - y0), 1)
        return self.silhouette if kp.mask[y0:y1, x0:x1].sum() >= 0.1 * area else 0.0

    def posed_body(self, rec: Reconstruction):
        """Re-run the body model from the reconstruction's parameters (camera frame)."""
        rot = torch.tensor(rec.rotmats, dtype=torch.float32)[None]
        shape = torch.tensor(rec.shape, dtype=torch.float32)[None]
        with torch.no_grad():
            return self.body(rot, shape, transl=torch.tensor(rec.translation, dtype=torch.float32)[None])


class SilhouetteTarget:
    """Differentiable silhouette terms against a person mask, for projected body vertices uv
    (N, 2) pixels: mean robust distance of the vertices outside the mask (every surface point
    projects inside the silhouette) + ``cover`` x mean robust distance from the mask's contour
    to the nearest vertex (the body should reach the contour). Distances are in units of the
    person box' longer side (``size``); the robust kernel d^2 / (d^2 + s^2) caps what a wrong
    mask (an occluder, a missed limb) can pull. Contour points on the image border are skipped
    (the body continues outside)."""

    def __init__(self, mask: np.ndarray, box, device="cpu", contour_points: int = 256, scale: float = 0.05,
                 cover: float = 1.0):
        import cv2

        m = np.ascontiguousarray(mask, dtype=np.uint8)
        h, w = m.shape
        self.size = float(max(box[2] - box[0], box[3] - box[1], 1.0))
        self.scale, self.cover = scale, cover
        dist = cv2.distanceTransform(1 - m, cv2.DIST_L2, 5) / self.size
        self.dist = torch.tensor(dist, dtype=torch.float32, device=device)[None, None]
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        c = np.concatenate([x[:, 0] for x in contours]) if contours else np.zeros((0, 2))
        c = c[(c[:, 0] > 0) & (c[:, 0] < w - 1) & (c[:, 1] > 0) & (c[:, 1] < h - 1)]
        if len(c) > contour_points:
            c = c[np.linspace(0, len(c) - 1, contour_points).astype(int)]
        self.contour = torch.tensor(c, dtype=torch.float32, device=device)
        self.contour_np = c.astype(np.float64)
        self.hw = (h, w)

    def rho(self, d2: torch.Tensor) -> torch.Tensor:
        return d2 / (d2 + self.scale ** 2)

    def outside(self, uv: torch.Tensor) -> torch.Tensor:
        """(N,) robust cost of each point's distance to the mask (0 inside it or off the image)."""
        h, w = self.hw
        grid = torch.stack([(uv[:, 0] + 0.5) / w * 2 - 1, (uv[:, 1] + 0.5) / h * 2 - 1], -1)
        d = torch.nn.functional.grid_sample(self.dist, grid[None, None], align_corners=False, padding_mode="zeros")
        return self.rho(d[0, 0, 0] ** 2)

    def uncovered(self, uv: torch.Tensor) -> torch.Tensor:
        """(C,) robust cost of each contour point's distance to its nearest point of uv."""
        from scipy.spatial import cKDTree

        if not len(self.contour):
            return uv.new_zeros(0)
        # the nearest point of each contour point (no gradient through the choice)
        nearest = torch.as_tensor(cKDTree(uv.detach().cpu().numpy()).query(self.contour_np)[1], device=uv.device)
        return self.rho((self.contour - uv[nearest]).pow(2).sum(-1) / self.size ** 2)  # no sqrt: finite gradient at 0

    def __call__(self, uv: torch.Tensor) -> torch.Tensor:
        loss = self.outside(uv).mean()
        if len(self.contour):
            loss = loss + self.cover * self.uncovered(uv).mean()
        return loss * self.scale ** 2  # ~ squared distance for small errors


def _linear_rest_geometry(body, shape: torch.Tensor, ids: torch.Tensor | None, with_jacobian: bool, eps: float = 1e-2):
    """The body's rest geometry (landmarks, then ``ids``) at ``shape`` (1, S) and, if asked, its
    Jacobian in the shape parameters by central differences in one batched call: a fitting
    loop then skips the shape blendshapes (most of a body call). anny's phenotype blends are
    piecewise linear, so the linear model holds for the small shape changes a fit makes (a test
    bounds its error; on synth-val the fit moved by 0.03 mm of P1 with it, IoU unchanged).
    Returns ((rest_v, rest_j), (jac_v, jac_j) | None)."""
    sel = body.landmark_indices if ids is None else torch.cat([body.landmark_indices, ids])
    with torch.no_grad():
        if not with_jacobian:
            return body.rest_geometry(shape, sel), None
        s = shape.shape[1]
        step = eps * torch.eye(s, dtype=shape.dtype, device=shape.device)
        batch = torch.cat([shape, shape + step, shape - step])
        if body.shape_range is not None:
            batch = batch.clamp(*body.shape_range)
        v, j = body.rest_geometry(batch, sel)
        h = (batch[1:s + 1] - batch[s + 1:]).diagonal().clamp_min(1e-6)  # actual steps after clamping
        jac = tuple(((x[1:s + 1] - x[s + 1:]) / h[:, None, None]).permute(1, 2, 0)[None] for x in (v, j))
        return (v[:1], j[:1]), jac


def place(points: np.ndarray, uv: np.ndarray, k: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Translation t minimising the (weighted) linearised reprojection error of points + t onto uv."""
    f, c = k[0, 0], k[:2, 2]
    w = np.ones(len(uv)) if weights is None else np.asarray(weights, float)
    a, b = [], []
    for d in range(2):
        du = uv[:, d] - c[d]
        row = np.zeros((len(uv), 3))
        row[:, d], row[:, 2] = f, -du
        a.append(row * w[:, None])
        b.append((du * points[:, 2] - f * points[:, d]) * w)
    t, *_ = np.linalg.lstsq(np.concatenate(a), np.concatenate(b), rcond=None)
    return t


def _in_image(uv: np.ndarray, shape) -> np.ndarray:
    """Placement weights: keypoints outside the image (guessed, e.g. legs of a half-body photo)
    count 10x less than those inside."""
    h, w = shape[:2]
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    return np.where(inside, 1.0, 0.1)


def _check_image(rgb) -> None:
    if not isinstance(rgb, np.ndarray) or rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError("expected an (H, W, 3) uint8 RGB array (use recon.io.load_image for files)")
