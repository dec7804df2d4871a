"""The files of one image of ``recon run``: ``body.obj``, the rigged ``body.glb``, ``pose.bvh``,
``overlay.png`` and ``side.png``, with an outfit ``outfit.obj`` and ``dressed.glb``, and
``result.json`` last (``people.json`` over ``person_<i>/`` folders with several people)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from recon import camera
from recon.body import skeleton
from recon.body.base import BodyModel
from recon.export.bvh import write_bvh
from recon.export.glb import INFLUENCES, write_glb
from recon.export.media import write_image
from recon.export.mesh import write_mesh
from recon.export.records import write_json
from recon.garment.morph import outfit_animation
from recon.reconstruction import Reconstruction
from recon.viz import draw_meshes, draw_overlay

BODY_RGBA = (0.45, 0.62, 0.92, 1.0)
DRESSED_BODY_RGBA = (0.85, 0.75, 0.68, 1.0)
OUTFIT_RGBA = (0.35, 0.45, 0.8, 1.0)
OVERLAY_COLOURS = (BODY_RGBA, (0.92, 0.55, 0.45, 1.0), (0.5, 0.82, 0.5, 1.0), (0.85, 0.75, 0.4, 1.0),
                   (0.7, 0.5, 0.85, 1.0))


def write_pose_bvh(path: Path, body: BodyModel, r: Reconstruction) -> Path:
    """The estimated pose as a one-frame BVH on the reconstructed body's own skeleton (its shape's
    rest joints), centimetres, in the view frame of the photo's camera (y up, z towards the camera)."""
    with torch.no_grad():
        rest = body(shape=torch.tensor(r.shape, dtype=torch.float32)[None]).joints[0].numpy()
    rot = r.rotmats.copy()
    rot[0] = camera.rotation_to_view(rot[0])
    return write_bvh(path, list(skeleton.JOINT_NAMES), list(skeleton.JOINT_PARENTS), rest, rot[None],
                     camera.to_view(r.translation)[None])


def write_rigged_glb(path: Path, body: BodyModel, r: Reconstruction, image_hw: tuple[int, int], k: np.ndarray,
                     dresser=None, tightness=None, influences: int | None = INFLUENCES) -> Path:
    """The reconstruction as a rigged .glb (skeleton, skinned body, the outfit with its PBNS blend
    shapes) in the photo camera's view frame (glTF's: +Y up, the camera at the origin looking down
    -Z), with that camera in the file."""
    rot = torch.tensor(r.rotmats[None], dtype=torch.float32)
    rot[0, 0] = torch.as_tensor(camera.rotation_to_view(r.rotmats[0]), dtype=torch.float32)
    transl = torch.tensor(camera.to_view(r.translation)[None], dtype=torch.float32)
    shape = torch.tensor(r.shape, dtype=torch.float32)
    outfit = None if dresser is None else outfit_animation(body, shape, rot, transl, dresser, tightness=tightness,
                                                          influences=influences)
    return write_glb(path, body, shape, rot, transl, outfit=outfit, camera=(k, image_hw), animation_name="photo",
                     influences=influences)


def write_people(folder: Path, src: Path, img, small, s: float, k_small, people: list[Reconstruction], rec,
                  options, dresser, focal_from: str, stamp: dict) -> None:
    """The people of one image: person_<i>/ each, one overlay with all, then people.json."""
    for i, r in enumerate(people):
        write_person(folder / f"person_{i}", src, img, small, s, k_small, r, rec, options, dresser, focal_from, stamp)
    if options.overlay:
        meshes = [(r.vertices, rec.faces, OVERLAY_COLOURS[i % len(OVERLAY_COLOURS)]) for i, r in enumerate(people)]
        write_image(folder / "overlay.png", draw_overlay(small, meshes, k_small))
    index = {"source": str(src), "image_size": list(img.shape[:2]), "count": len(people),
             "people": [{"folder": f"person_{i}", "box": np.round(np.asarray(r.keypoints.box) / s, 1).tolist(),
                         "confidence": round(r.keypoints.confidence, 4)} for i, r in enumerate(people)],
             "made_from": stamp}
    write_json(folder / "people.json", index)


def write_one(folder: Path, src: Path, img, small, s: float, k_small, people: list[Reconstruction], rec,
               options, dresser, focal_from: str, stamp: dict) -> None:
    write_person(folder, src, img, small, s, k_small, people[0], rec, options, dresser, focal_from, stamp)


def write_person(folder: Path, src: Path, img, small, s: float, k_small, r: Reconstruction, rec, options,
           dresser, focal_from: str, stamp: dict) -> None:
    """Outputs of one person; result.json last. ``focal_from``: where the intrinsics' focal length
    came from ("exif" or "default"), recorded in result.json."""
    folder.mkdir(parents=True, exist_ok=True)
    faces, tightness = rec.faces, options.tightness
    influences = None if options.all_influences else INFLUENCES
    write_mesh(folder / "body.obj", r.vertices, faces)
    write_rigged_glb(folder / "body.glb", rec.body, r, small.shape[:2], k_small, influences=influences)
    write_pose_bvh(folder / "pose.bvh", rec.body, r)
    meshes = [(r.vertices, faces, BODY_RGBA)]
    if dresser is not None:
        # the body's root rotation is into the camera frame; the outfit's network needs gravity
        # (+Y up of the body frame), i.e. an upright camera: the view frame
        d = dresser(rec.body, torch.tensor(r.rotmats[None], dtype=torch.float32),
                    torch.tensor(r.shape, dtype=torch.float32), torch.tensor(r.translation[None], dtype=torch.float32),
                    up=torch.tensor(camera.HALF_TURN_X, dtype=torch.float32), tightness=tightness)
        write_mesh(folder / "outfit.obj", d.vertices[0], d.faces)
        write_rigged_glb(folder / "dressed.glb", rec.body, r, small.shape[:2], k_small, dresser, tightness,
                         influences)
        meshes = [(r.vertices, faces, DRESSED_BODY_RGBA), (d.vertices[0], d.faces, OUTFIT_RGBA)]
    if options.overlay:
        write_image(folder / "overlay.png", draw_overlay(small, meshes, k_small))
        if min(small.shape[:2]) >= 64:
            side = draw_meshes([(camera.to_view(m[0]), m[1], m[2]) for m in meshes],
                               size=(small.shape[0] // 2 * 2, ) * 2, yaw_deg=90)
            write_image(folder / "side.png", side)
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
        if dresser.garment_model != "pbns":
            js["outfit"]["garment_model"] = dresser.garment_model
    js["files"] = sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))
    js["made_from"] = stamp
    write_json(folder / "result.json", js)
