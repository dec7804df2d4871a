"""``recon run``: reconstruct every image of files/folders into an output folder.

Per image ``<out>/<key>/``: ``result.json`` (2D/3D joints and landmarks, pose, shape, camera,
confidence), ``body.obj`` (mesh in the camera frame), ``body.glb`` (rigged: skeleton and skinned
body in the photo's pose, in the view frame, with the photo's camera), ``pose.bvh`` (the pose on
the body's skeleton, one frame), ``overlay.png`` (mesh over the photo) and ``side.png`` (side
view); with an outfit also ``outfit.obj`` and ``dressed.glb`` (rigged, with the outfit's blend
shapes).
With ``--max-people N`` an image with several people gets ``person_0/``, ``person_1/``, ...
(the largest first), one ``overlay.png`` with all of them and ``people.json``. Every file is
written atomically and ``result.json`` (``people.json``) last, so a folder with one is
complete: a re-run skips it (resume after Ctrl-C or a crash). Images that fail (unreadable, no
person, ...) are reported with the reason and the batch goes on; ``<out>/summary.json`` lists
done / skipped / failed.
"""
from __future__ import annotations

import json
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch
import trimesh
from tqdm import tqdm

from recon import camera, paths
from recon.body import skeleton
from recon.errors import ReconError
from recon.garment.dress import Dresser
from recon.garment.gltf import write_glb
from recon.io import ImageError, exif_focal_factor, list_images, load_image
from recon.pipeline import Reconstruction, Reconstructor
from recon.poses.bvh import write_bvh
from recon.viz import render_meshes, render_overlay

MAX_SIDE = 1920  # longer side used for detection/rendering; results are in original pixels
BODY_RGBA = (0.45, 0.62, 0.92, 1.0)
DRESSED_BODY_RGBA = (0.85, 0.75, 0.68, 1.0)
OUTFIT_RGBA = (0.35, 0.45, 0.8, 1.0)
OVERLAY_COLOURS = (BODY_RGBA, (0.92, 0.55, 0.45, 1.0), (0.5, 0.82, 0.5, 1.0), (0.85, 0.75, 0.4, 1.0),
                   (0.7, 0.5, 0.85, 1.0))


@dataclass
class RunSummary:
    done: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)  # finished by an earlier run
    failed: dict[str, str] = field(default_factory=dict)  # key -> reason
    interrupted: bool = False
    seconds: float = 0.0

    def to_json(self) -> dict:
        return {"done": len(self.done), "skipped": len(self.skipped), "failed": len(self.failed),
                "interrupted": self.interrupted, "seconds": round(self.seconds, 1),
                "failures": self.failed, "done_keys": self.done, "skipped_keys": self.skipped}

    def line(self) -> str:
        s = f"done {len(self.done)}, skipped (already done) {len(self.skipped)}, failed {len(self.failed)}"
        return s + (" - interrupted: run the same command again to resume" if self.interrupted else "")


def check_writable(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=out, prefix=".write-test-")
        os.close(fd)
        os.unlink(tmp)
    except OSError as e:
        raise ReconError(f"output folder {out} is not writable: {e.strerror or e}") from e


def run(inputs: list[str | Path], out: str | Path, reconstructor: Reconstructor | None = None, batch_size: int = 4,
        overlay: bool = True, outfit: str | None = None, tightness: tuple[float, float] | None = None,
        progress: bool = True, log=print, exif_focal: bool = True, max_people: int = 1) -> RunSummary:
    """Reconstruct every image of ``inputs`` into ``out`` (see the module doc). ``reconstructor``:
    default ``Reconstructor()`` (``recon run``'s defaults), built when the first image loads; the
    fit comes from it, and its ``focal_factor`` for images whose EXIF gives no 35 mm equivalent
    focal length (``exif_focal``: read it; False: always the reconstructor's). ``outfit``: dress
    the bodies with a trained PBNS outfit, resized to each body and, with ``tightness`` (2,) and a
    trained resizer, looser or tighter. ``max_people``: people per image (the largest first); an
    image with more than one gets ``person_0/``, ``person_1/``, ... (each as above), one
    ``overlay.png`` with all of them and ``people.json`` (written last, it marks the image done).
    """
    out = Path(out)
    check_writable(out)
    items = list_images(inputs)
    summary, t0 = RunSummary(), time.time()
    summary.skipped = [k for _, k in items if any((out / k / f).exists() for f in ("result.json", "people.json"))]
    todo = [(p, k) for p, k in items if k not in set(summary.skipped)]
    if not items:
        log(f"no images found in {', '.join(map(str, inputs))}")
    dresser = None
    if outfit:
        dresser = Dresser(outfit)  # fails early (clear message) if the outfit is not trained
        if tightness is not None and not dresser.has_resizer:
            raise ReconError(f"--tightness needs a trained resizer for {outfit}: "
                             f"run `recon garment resize --outfit {outfit}`")
    elif tightness is not None:
        raise ReconError("--tightness needs --outfit")
    rec = reconstructor
    bar = tqdm(total=len(todo), desc="recon run", unit="img", disable=not progress)
    try:
        for b in range(0, len(todo), batch_size):
            loaded = []
            for p, key in todo[b:b + batch_size]:
                try:
                    loaded.append((p, key, load_image(p)))
                except ImageError as e:
                    summary.failed[key] = str(e)
                    log(f"failed: {e}")
                    bar.update(1)
            if not loaded:
                continue
            rec = rec or Reconstructor()
            small = [_downscale(img) for _, _, img in loaded]
            focal = [(exif_focal_factor(p) if exif_focal else None) for p, _, _ in loaded]
            ks = [np.diag([s, s, 1.0]) @ camera.default_intrinsics(*img.shape[:2], f or rec.focal_factor)
                  for (_, _, img), (_, s), f in zip(loaded, small, focal, strict=True)]
            images = [im for im, _ in small]
            results = (rec.people(images, ks, max_people) if max_people > 1
                       else [r if isinstance(r, Exception) else [r] for r in rec.batch(images, ks)])
            for (p, key, img), (im, s), k, r, f in zip(loaded, small, ks, results, focal, strict=True):
                if isinstance(r, Exception):
                    summary.failed[key] = f"{p}: {r}"
                    log(f"failed: {p}: {r}")
                else:
                    try:
                        focal_from = "exif" if f else "default"
                        if len(r) == 1:
                            _write(out / key, p, img, im, s, k, r[0], rec, overlay, dresser, tightness, focal_from)
                        else:
                            _write_people(out / key, p, img, im, s, k, r, rec, overlay, dresser, tightness, focal_from)
                        summary.done.append(key)
                    except OSError as e:
                        summary.failed[key] = f"{p}: cannot write outputs ({e})"
                        log(f"failed: {p}: cannot write outputs ({e})")
                bar.update(1)
    except KeyboardInterrupt:
        summary.interrupted = True
    finally:
        bar.close()
        summary.seconds = time.time() - t0
        try:
            paths.write_text(out / "summary.json", json.dumps(summary.to_json(), indent=1))
        except OSError:
            pass
    log(summary.line())
    return summary


def _downscale(img: np.ndarray) -> tuple[np.ndarray, float]:
    s = min(1.0, MAX_SIDE / max(img.shape[:2]))
    if s == 1.0:
        return img, 1.0
    size = (round(img.shape[1] * s), round(img.shape[0] * s))
    return cv2.resize(img, size, interpolation=cv2.INTER_AREA), s


def write_pose_bvh(path: Path, body, r: Reconstruction) -> Path:
    """The estimated pose as a one-frame BVH on the reconstructed body's own skeleton (its shape's
    rest joints), centimetres, in the view frame of the photo's camera (y up, z towards the camera)."""
    with torch.no_grad():
        rest = body(shape=torch.tensor(r.shape, dtype=torch.float32)[None]).joints[0].numpy()
    rot = r.rotmats.copy()
    rot[0] = camera.rotation_to_view(rot[0])
    return write_bvh(path, list(skeleton.JOINT_NAMES), list(skeleton.JOINT_PARENTS), rest, rot[None],
                     camera.to_view(r.translation)[None])


def write_rigged_glb(path: Path, body, r: Reconstruction, image_hw: tuple[int, int], k: np.ndarray, dresser=None,
                     tightness=None) -> Path:
    """The reconstruction as a rigged .glb (skeleton, skinned body, the outfit with its PBNS blend
    shapes) in the photo camera's view frame (glTF's: +Y up, the camera at the origin looking down
    -Z), with that camera in the file."""
    rot = torch.tensor(r.rotmats[None], dtype=torch.float32)
    rot[0, 0] = torch.as_tensor(camera.rotation_to_view(r.rotmats[0]), dtype=torch.float32)
    transl = torch.tensor(camera.to_view(r.translation)[None], dtype=torch.float32)
    return write_glb(path, body, torch.tensor(r.shape, dtype=torch.float32), rot, transl, dresser=dresser,
                     tightness=tightness, camera=(k, image_hw), animation_name="photo")


def _write_people(folder: Path, src: Path, img, small, s: float, k_small, people: list[Reconstruction],
                  rec: Reconstructor, overlay: bool, dresser, tightness, focal_from: str) -> None:
    """Several people of one image: person_<i>/ each, then one overlay with all, then people.json."""
    for i, r in enumerate(people):
        _write(folder / f"person_{i}", src, img, small, s, k_small, r, rec, overlay, dresser, tightness, focal_from)
    if overlay:
        meshes = [(r.vertices, rec.faces, OVERLAY_COLOURS[i % len(OVERLAY_COLOURS)]) for i, r in enumerate(people)]
        paths.write_image(folder / "overlay.png", render_overlay(small, meshes, k_small))
    index = {"source": str(src), "image_size": list(img.shape[:2]), "count": len(people),
             "people": [{"folder": f"person_{i}", "box": np.round(np.asarray(r.keypoints.box) / s, 1).tolist(),
                         "confidence": round(r.keypoints.confidence, 4)} for i, r in enumerate(people)]}
    paths.write_text(folder / "people.json", json.dumps(index, indent=1))


def _write(folder: Path, src: Path, img, small, s: float, k_small, r: Reconstruction, rec: Reconstructor,
           overlay: bool, dresser=None, tightness=None, focal_from: str = "default") -> None:
    """Outputs of one image; result.json last (it marks the folder complete). ``focal_from``: where
    the intrinsics' focal length came from ("exif" or "default"), recorded in result.json."""
    folder.mkdir(parents=True, exist_ok=True)
    faces = rec.faces
    mesh = trimesh.Trimesh(r.vertices, faces, process=False)
    paths.atomic_write(folder / "body.obj", lambda t: mesh.export(t, file_type="obj"))
    write_rigged_glb(folder / "body.glb", rec.body, r, small.shape[:2], k_small)
    write_pose_bvh(folder / "pose.bvh", rec.body, r)
    meshes = [(r.vertices, faces, BODY_RGBA)]
    if dresser is not None:
        # the body's root rotation is into the camera frame; the outfit's network needs gravity
        # (+Y up of the body frame), i.e. an upright camera: the view frame
        d = dresser(rec.body, torch.tensor(r.rotmats[None], dtype=torch.float32),
                    torch.tensor(r.shape, dtype=torch.float32), torch.tensor(r.translation[None], dtype=torch.float32),
                    up=torch.tensor(camera.HALF_TURN_X, dtype=torch.float32), tightness=tightness)
        cloth = trimesh.Trimesh(d.vertices[0], d.faces, process=False)
        paths.atomic_write(folder / "outfit.obj", lambda t: cloth.export(t, file_type="obj"))
        write_rigged_glb(folder / "dressed.glb", rec.body, r, small.shape[:2], k_small, dresser, tightness)
        meshes = [(r.vertices, faces, DRESSED_BODY_RGBA), (d.vertices[0], d.faces, OUTFIT_RGBA)]
    if overlay:
        paths.write_image(folder / "overlay.png", render_overlay(small, meshes, k_small))
        if min(small.shape[:2]) >= 64:
            side = render_meshes([(camera.to_view(m[0]), m[1], m[2]) for m in meshes],
                                 size=(small.shape[0] // 2 * 2, ) * 2, yaw_deg=90)
            paths.write_image(folder / "side.png", side)
    js = r.to_json()
    if s != 1.0:  # back to the original image's pixels: same 3D, focal and 2D scaled by 1/s
        k = r.K.copy()
        k[:2] /= s
        js["camera"]["K"] = np.round(k, 3).tolist()
        for key in ("joints2d", "landmarks2d", "keypoints2d_detected"):
            js[key] = np.round(np.asarray(js[key]) / s, 2).tolist()
        js["box"] = np.round(np.asarray(js["box"]) / s, 1).tolist()
        js["reprojection_error_px"] = round(js["reprojection_error_px"] / s, 2)
    js["camera"]["focal_from"] = focal_from
    js["image_size"] = list(img.shape[:2])
    js["source"] = str(src)
    js["keypoint_source"] = getattr(getattr(rec, "source", None), "name", None)
    if dresser is not None:
        js["outfit"] = {"name": dresser.outfit, "garments": dresser.names,
                        "tightness": None if tightness is None else [float(t) for t in tightness]}
    js["files"] = sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))
    paths.write_text(folder / "result.json", json.dumps(js, indent=1))
