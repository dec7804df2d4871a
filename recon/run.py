"""``recon run``: reconstruct every image of files/folders into an output folder.

Per image ``<out>/<key>/`` (``key``: the path relative to the given folder, without its suffix;
``recon.io.scan_inputs``): ``result.json`` (2D/3D joints and landmarks, pose, shape, camera,
confidence, what it was made from), ``body.obj`` (mesh in the camera frame), ``body.glb``
(rigged: skeleton and skinned body in the photo's pose, in the view frame, with the photo's
camera), ``pose.bvh`` (the pose on the body's skeleton, one frame), ``overlay.png`` (mesh over the
photo) and ``side.png`` (side view); with an outfit also ``outfit.obj`` and ``dressed.glb``.
With ``max_people`` > 1 every image folder holds ``person_0/``, ``person_1/``, ... (each as above,
the largest person first, however many were found), one ``overlay.png`` and ``people.json``.

An image folder is written in a staging folder and moved into place whole, so a folder is either
complete or absent (Ctrl-C, kill -9, a full disk). A complete folder made from the same file bytes,
options and recon version is left as it is (``unchanged``); otherwise it is made again (``--force``:
always). ``<out>/summary.json`` lists every file seen: done, unchanged, no person found, skipped
(not an image or unreadable, with the reason) and failed (an error while reconstructing or writing).
"""
from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import tempfile
import time
import uuid
from dataclasses import asdict, dataclass, field
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
from recon.io import ImageError, Input, exif_focal_factor, file_digest, load_image, scan_inputs
from recon.pipeline import NoPersonFound, Reconstruction, Reconstructor, ReconstructorConfig
from recon.poses.bvh import write_bvh
from recon.version import __version__
from recon.viz import render_meshes, render_overlay

MAX_SIDE = 1920  # longer side used for detection/rendering; results are in original pixels
BODY_RGBA = (0.45, 0.62, 0.92, 1.0)
DRESSED_BODY_RGBA = (0.85, 0.75, 0.68, 1.0)
OUTFIT_RGBA = (0.35, 0.45, 0.8, 1.0)
OVERLAY_COLOURS = (BODY_RGBA, (0.92, 0.55, 0.45, 1.0), (0.5, 0.82, 0.5, 1.0), (0.85, 0.75, 0.4, 1.0),
                   (0.7, 0.5, 0.85, 1.0))
STAGING = ".recon-staging"  # under the output folder: image folders being written
log_ = logging.getLogger(__name__)


@dataclass
class RunOptions:
    """What ``recon run`` makes of each image besides the reconstruction (``ReconstructorConfig``).

    outfit: dress the bodies with a trained outfit, resized to each body; tightness: (2,) looser
    (> 0) or tighter (< 0), needs the outfit's resizer. max_people: people per image (> 1: the
    ``person_<i>/`` layout). overlay: write overlay.png and side.png. exif_focal: the focal length
    from the photo's EXIF where it has one (else the config's ``focal_factor``). batch_size: images
    per SMPLR/fit batch. force: make every image again, even those already done. garment_model:
    "pbns" or "taylor" (recon.garment.Dresser).
    """

    outfit: str | None = None
    tightness: tuple[float, float] | None = None
    max_people: int = 1
    overlay: bool = True
    exif_focal: bool = True
    batch_size: int = 4
    force: bool = False
    garment_model: str = "pbns"

    def to_json(self) -> dict:
        """The options that change the outputs (not batch size or force; the garment model only
        when it is not the default, so that earlier runs' outputs stay theirs)."""
        d = asdict(self)
        d["tightness"] = None if self.tightness is None else [float(t) for t in self.tightness]
        skip = ("batch_size", "force") + (("garment_model",) if self.garment_model == "pbns" else ())
        return {k: v for k, v in d.items() if k not in skip}


@dataclass
class RunSummary:
    done: list[str] = field(default_factory=list)  # keys made by this run
    unchanged: list[str] = field(default_factory=list)  # keys an earlier run made from the same file and options
    no_person: dict[str, str] = field(default_factory=dict)  # key -> source: nobody found in the image
    skipped: dict[str, str] = field(default_factory=dict)  # path -> why it is not an image recon can read
    failed: dict[str, str] = field(default_factory=dict)  # path -> error while reconstructing or writing
    interrupted: bool = False
    seconds: float = 0.0

    def to_json(self) -> dict:
        counts = {k: len(getattr(self, k)) for k in ("done", "unchanged", "no_person", "skipped", "failed")}
        return {"recon": __version__, "counts": counts, "interrupted": self.interrupted,
                "seconds": round(self.seconds, 1), "done": self.done, "unchanged": self.unchanged,
                "no_person": self.no_person, "skipped": self.skipped, "failed": self.failed}

    def line(self) -> str:
        s = (f"done {len(self.done)}, unchanged {len(self.unchanged)}, no person found {len(self.no_person)}, "
             f"skipped {len(self.skipped)} (not images or unreadable), failed {len(self.failed)}")
        return s + (" - interrupted: run the same command again to resume" if self.interrupted else "")


def check_writable(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=out, prefix=".write-test-")
        os.close(fd)
        os.unlink(tmp)
    except OSError as e:
        raise ReconError(f"output folder {out} is not writable: {e.strerror or e}") from e


def made_from(digest: str, options: RunOptions, config: ReconstructorConfig) -> dict:
    """What a result is made from: the input's bytes, the options and config, recon's version."""
    return {"recon": __version__, "input_sha256": digest, "options": options.to_json(),
            "reconstructor": config.to_json()}


def recorded(folder: Path) -> dict | None:
    """The ``made_from`` of a complete image folder (result.json or people.json), else None."""
    for name in ("result.json", "people.json"):
        try:
            return json.loads((folder / name).read_text()).get("made_from", {})
        except (OSError, ValueError):
            continue
    return None


def run(inputs: list[str | Path], out: str | Path, options: RunOptions | None = None,
        config: ReconstructorConfig | None = None, reconstructor: Reconstructor | None = None,
        progress: bool = True, log=print) -> RunSummary:
    """Reconstruct every image of ``inputs`` into ``out`` (see the module doc). ``config``: the
    reconstruction (default ``recon run``'s); ``reconstructor``: one already built (its config is
    used), else one is built when the first image needs it."""
    options = options or RunOptions()
    if options.max_people < 1 or options.batch_size < 1:
        raise ReconError("max_people and batch_size must be at least 1")
    config = reconstructor.config if reconstructor is not None else (config or ReconstructorConfig()).as_installed()
    out = Path(out)
    dresser = _dresser(options)
    check_writable(out)
    staging = _staging(out)
    scan = scan_inputs(inputs)
    summary, t0 = RunSummary(skipped=dict(scan.skipped)), time.time()
    for path, reason in scan.skipped.items():
        log(f"skipped: {path}: {reason}")
    todo = []
    for item in scan.files:
        try:
            digest = file_digest(item.path)
        except OSError as e:
            summary.skipped[str(item.path)] = f"cannot read ({e.strerror or e})"
            log(f"skipped: {item.path}: cannot read ({e.strerror or e})")
            continue
        stamp = made_from(digest, options, config)
        if not options.force and recorded(out / item.key) == stamp:
            summary.unchanged.append(item.key)
        else:
            todo.append((item, stamp))
    if not scan.files and not scan.skipped:
        log(f"no files found in {', '.join(map(str, inputs))}")
    rec = reconstructor
    bar = tqdm(total=len(todo), desc="recon run", unit="img", disable=not progress)
    try:
        for b in range(0, len(todo), options.batch_size):
            loaded = []
            for item, stamp in todo[b:b + options.batch_size]:
                try:
                    loaded.append((item, stamp, load_image(item.path)))
                except ImageError as e:
                    summary.skipped[str(item.path)] = _reason(e, item.path)
                    log(f"skipped: {e}")
                    bar.update(1)
            if not loaded:
                continue
            rec = rec or Reconstructor(config)
            small = [_downscale(img) for _, _, img in loaded]
            focal = [(exif_focal_factor(item.path) if options.exif_focal else None) for item, _, _ in loaded]
            ks = [np.diag([s, s, 1.0]) @ camera.default_intrinsics(*img.shape[:2], f or rec.focal_factor)
                  for (_, _, img), (_, s), f in zip(loaded, small, focal, strict=True)]
            try:
                results = rec.people([im for im, _ in small], ks, options.max_people)
            except (KeyboardInterrupt, ReconError):
                raise
            except Exception as e:  # noqa: BLE001 - one batch's bug must not stop a folder of thousands
                log_.debug("reconstruction failed", exc_info=True)
                results = [e] * len(loaded)
            for (item, stamp, img), (im, s), k, r, f in zip(loaded, small, ks, results, focal, strict=True):
                _finish(summary, out, staging, item, stamp, img, im, s, k, r, rec, options, dresser,
                        "exif" if f else "default", log)
                bar.update(1)
    except KeyboardInterrupt:
        summary.interrupted = True
    finally:
        bar.close()
        summary.seconds = time.time() - t0
        shutil.rmtree(staging, ignore_errors=True)
        with contextlib.suppress(OSError):
            staging.parent.rmdir()  # when no other run is writing here
        try:
            paths.write_text(out / "summary.json", json.dumps(summary.to_json(), indent=1))
        except OSError:
            pass
    log(summary.line())
    return summary


def _dresser(options: RunOptions) -> Dresser | None:
    """The outfit's Dresser, refused before any image when the outfit or its resizer is missing."""
    if not options.outfit:
        if options.tightness is not None:
            raise ReconError("--tightness needs --outfit")
        return None
    dresser = Dresser(options.outfit, garment_model=options.garment_model)
    if options.tightness is not None and dresser.taylor is not None:
        raise ReconError("--tightness is the resizer's: the Taylor garment model has none")
    if options.tightness is not None and not dresser.has_resizer:
        raise ReconError(f"--tightness needs a trained resizer for {options.outfit}: "
                         f"run `recon garment resize --outfit {options.outfit}`")
    return dresser


def _staging(out: Path) -> Path:
    """This run's staging folder; those of runs that are no longer alive are removed."""
    root = out / STAGING
    if root.is_dir():
        for d in root.iterdir():
            pid = d.name.split("-")[0]
            if not (pid.isdigit() and _alive(int(pid))):
                shutil.rmtree(d, ignore_errors=True)
    path = root / f"{os.getpid()}-{uuid.uuid4().hex[:8]}"
    path.mkdir(parents=True)
    return path


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return False  # an earlier run of this process (the API called twice) is over
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _reason(e: Exception, path: Path) -> str:
    """An error's message without the path in front (the summary lists it by path)."""
    msg = str(e)
    return msg[len(str(path)) + 2:] if msg.startswith(f"{path}: ") else msg


def _finish(summary: RunSummary, out: Path, staging: Path, item: Input, stamp: dict, img, small, s: float, k,
            result, rec, options: RunOptions, dresser, focal_from: str, log) -> None:
    """Files of one image written in a staging folder, then moved into place; the summary updated."""
    if isinstance(result, NoPersonFound):
        summary.no_person[item.key] = str(item.path)
        log(f"no person found: {item.path}")
        return
    if isinstance(result, Exception):
        summary.failed[str(item.path)] = f"reconstruction failed: {result!r} (a bug: please report it; -v shows more)"
        log(f"failed: {item.path}: {summary.failed[str(item.path)]}")
        return
    tmp = staging / uuid.uuid4().hex
    try:
        people = result if options.max_people > 1 else result[:1]
        write = _write_people if options.max_people > 1 else _write_one
        write(tmp, item.path, img, small, s, k, people, rec, options, dresser, focal_from, stamp)
        _move_into_place(tmp, out / item.key, staging)
        summary.done.append(item.key)
    except OSError as e:
        summary.failed[str(item.path)] = f"cannot write outputs ({e.strerror or e})"
        log(f"failed: {item.path}: cannot write outputs ({e.strerror or e})")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _move_into_place(tmp: Path, dst: Path, staging: Path) -> None:
    """Replace ``dst`` by the finished folder ``tmp``: two renames on one file system."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.exists() or dst.is_symlink():
        old = staging / f"old-{uuid.uuid4().hex}"
        os.rename(dst, old)
        os.rename(tmp, dst)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.rename(tmp, dst)


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


def _write_people(folder: Path, src: Path, img, small, s: float, k_small, people: list[Reconstruction], rec,
                  options: RunOptions, dresser, focal_from: str, stamp: dict) -> None:
    """The people of one image: person_<i>/ each, one overlay with all, then people.json."""
    for i, r in enumerate(people):
        _write(folder / f"person_{i}", src, img, small, s, k_small, r, rec, options, dresser, focal_from, stamp)
    if options.overlay:
        meshes = [(r.vertices, rec.faces, OVERLAY_COLOURS[i % len(OVERLAY_COLOURS)]) for i, r in enumerate(people)]
        paths.write_image(folder / "overlay.png", render_overlay(small, meshes, k_small))
    index = {"source": str(src), "image_size": list(img.shape[:2]), "count": len(people),
             "people": [{"folder": f"person_{i}", "box": np.round(np.asarray(r.keypoints.box) / s, 1).tolist(),
                         "confidence": round(r.keypoints.confidence, 4)} for i, r in enumerate(people)],
             "made_from": stamp}
    paths.write_text(folder / "people.json", json.dumps(index, indent=1))


def _write_one(folder: Path, src: Path, img, small, s: float, k_small, people: list[Reconstruction], rec,
               options: RunOptions, dresser, focal_from: str, stamp: dict) -> None:
    _write(folder, src, img, small, s, k_small, people[0], rec, options, dresser, focal_from, stamp)


def _write(folder: Path, src: Path, img, small, s: float, k_small, r: Reconstruction, rec, options: RunOptions,
           dresser, focal_from: str, stamp: dict) -> None:
    """Outputs of one person; result.json last. ``focal_from``: where the intrinsics' focal length
    came from ("exif" or "default"), recorded in result.json."""
    folder.mkdir(parents=True, exist_ok=True)
    faces, tightness = rec.faces, options.tightness
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
    if options.overlay:
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
        if dresser.garment_model != "pbns":
            js["outfit"]["garment_model"] = dresser.garment_model
    js["files"] = sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))
    js["made_from"] = stamp
    paths.write_text(folder / "result.json", json.dumps(js, indent=1))
