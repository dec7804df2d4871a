"""``recon animate``: a reconstructed person (its body shape, its outfit) moved by a mocap clip.

The body comes from a photo (run through ``recon run`` first), a ``recon run`` result folder or
a ``recon video`` track folder; the motion from a BVH (CMU, Daz, Mixamo skeletons, or recon's own, e.g. a ``pose.bvh``),
an ASF/AMC pair, or a clip of the shipped pose set by name or category (``recon animate
--list-motions``; a category takes its first held-out clip).
The clip is retargeted to the person's own skeleton (recon.poses.retarget), resampled to
30 fps and put on the ground (its lowest point at y = 0). Outputs: ``animated.glb`` (skeleton,
skinned body and outfit, per-frame blend-shape weights; recon.export.glb) and a render,
``animated.mp4`` (``animated.gif`` where OpenCV has no MP4 encoder, or when asked for).
Frames are in the body frame: +Y up, metres.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import roma
import torch
from tqdm import tqdm

from recon.body import default_body, skeleton
from recon.body.base import BodyModel
from recon.errors import MissingFile, ReconError
from recon.export.glb import INFLUENCES, write_glb
from recon.export.media import write_video
from recon.export.records import write_json
from recon.garment.dress import DressedOutfit, Dresser
from recon.garment.morph import outfit_animation
from recon.io import load_image
from recon.page import try_write_page
from recon.poses.asfamc import read_asf_amc
from recon.poses.bvh import read_bvh
from recon.poses.mocap import FPS, MocapPoses, poses_path, resample
from recon.poses.motion import SourceMotion, local_rotations
from recon.poses.retarget import Retargeter
from recon.reconstruction import NoPersonFound
from recon.run import RunOptions, run
from recon.viz import SequenceRenderer

BODY_RGBA = (0.85, 0.75, 0.68, 1.0)
OUTFIT_RGBA = (0.35, 0.45, 0.8, 1.0)


@dataclass
class Motion:
    """Local joint rotations (T, 24, 3, 3) and pelvis positions (T, 3) at ``fps``, body frame."""

    rotmats: torch.Tensor
    transl: torch.Tensor
    fps: float
    name: str

    def __len__(self) -> int:
        return int(self.rotmats.shape[0])

    def first(self, seconds: float | None) -> Motion:
        """The clip's first ``seconds`` (at least one frame); the whole clip for None or 0."""
        if not seconds:
            return self
        keep = max(1, int(round(seconds * self.fps)))
        return Motion(self.rotmats[:keep], self.transl[:keep], self.fps, self.name)


@lru_cache(maxsize=1)
def _pose_set(path: Path) -> MocapPoses:
    return MocapPoses.load(path=path)


def shipped_clips() -> list[dict]:
    """The clips of the shipped pose set (name, category, frames, split)."""
    return _pose_set(poses_path()).clips


def _retargeter(body: BodyModel, shape: torch.Tensor) -> Retargeter:
    """The retargeter to the body of ``shape``: its rest joints and landmarks."""
    with torch.no_grad():
        rest = body(shape=shape.reshape(1, -1))
    return Retargeter(rest.joints[0].numpy(), rest.landmarks[0].numpy())


def _own_skeleton(m: SourceMotion) -> tuple[np.ndarray, np.ndarray]:
    """A BVH on recon's own skeleton (``recon run``'s pose.bvh): its rotations are ours already."""
    order = [m.index(n) for n in skeleton.JOINT_NAMES]
    return local_rotations(m.rotations[:, order], skeleton.JOINT_PARENTS), m.positions[:, order[0]]


def clip_name(spec: str, clips: list[dict]) -> str:
    """A shipped clip by name, or by category (its first held-out clip: test, then val, then train)."""
    names = [c["name"] for c in clips]
    if spec in names:
        return spec
    order = {"test": 0, "val": 1, "train": 2}
    of_kind = sorted((c for c in clips if c["category"] == spec), key=lambda c: order[c["split"]])
    if of_kind:
        return of_kind[0]["name"]
    close = [n for n in names if spec.lower() in n.lower()][:8]
    hint = f" (did you mean: {', '.join(close)}?)" if close else ""
    kinds = ", ".join(sorted({c["category"] for c in clips}))
    raise ReconError(f"no motion {spec!r}: give a .bvh/.amc file, a shipped clip's name{hint} or a category "
                     f"({kinds}); `recon animate --list-motions` lists the clips")


def check_motion(spec: str | Path) -> None:
    """Refuse a motion that cannot load before any work is done (a missing file, an unknown name)."""
    p = Path(spec)
    if p.suffix.lower() in (".bvh", ".amc"):
        if not p.exists():
            raise MissingFile(f"motion file {p} not found")
    else:
        clip_name(str(spec), shipped_clips())


def load_motion(spec: str | Path, body: BodyModel, shape: torch.Tensor, asf: str | Path | None = None) -> Motion:
    """A clip for the body of ``shape``: a .bvh, an .amc (with ``asf`` or the one .asf beside it),
    or a shipped clip's name or category."""
    p = Path(spec)
    if p.suffix.lower() in (".bvh", ".amc"):
        if not p.exists():
            raise MissingFile(f"motion file {p} not found")
        if p.suffix.lower() == ".amc":
            skel = Path(asf) if asf else None
            if skel is None:
                found = sorted(p.parent.glob("*.asf"))
                if len(found) != 1:
                    raise ReconError(f"{p}: an .amc needs its skeleton: pass --asf FILE.asf "
                                     f"({len(found)} .asf files beside it)")
                skel = found[0]
            source = read_asf_amc(skel, p)
        else:
            source = read_bvh(p)
        if set(skeleton.JOINT_NAMES) <= set(source.names):
            rot, tr = _own_skeleton(source)
            tr = tr / 100.0 if np.abs(tr).max() > 20 else tr  # our BVHs are in centimetres
        else:
            res = _retargeter(body, shape).retarget(source)  # unsupported skeletons raise here
            rot, tr = res.rotmats, res.transl
        rot, tr = resample(rot, tr, source.fps, FPS)
        return Motion(torch.from_numpy(np.asarray(rot, np.float32)), torch.from_numpy(np.asarray(tr, np.float32)),
                      FPS, p.stem)
    m = _pose_set(poses_path())
    names = [c["name"] for c in m.clips]
    name = clip_name(str(spec), m.clips)
    sel = np.nonzero(m.clip == names.index(name))[0]
    rot = roma.rotvec_to_rotmat(torch.from_numpy(m.rotvec[sel]).float())
    # the set is retargeted to the default body: scale the root's path to this body's legs
    ratio = _retargeter(body, shape).leg_length / _retargeter(default_body(), default_body().mean_shape).leg_length
    tr = torch.from_numpy(m.transl[sel]).float() * float(ratio)
    return Motion(rot, tr, FPS, name)


def person_from(source: str | Path, out: Path, outfit: str | None = None, log=print) -> dict:
    """result.json of the person to animate: ``source`` is a ``recon run`` result folder (or its
    result.json), a ``recon video`` track folder (or its motion.json: the track's body shape) or a
    photo, which is reconstructed into ``out/reconstruction`` first."""
    p = Path(source)
    if p.is_dir() and not (p / "result.json").exists() and (p / "motion.json").exists():
        p = p / "motion.json"
    if p.name == "motion.json" and p.is_file():
        return json.loads(p.read_text())
    if p.is_dir() and not (p / "result.json").exists():
        found = sorted(p.glob("*/result.json"))
        if len(found) != 1:
            raise ReconError(f"{p}: not a `recon run` result folder (no result.json"
                             + (f"; {len(found)} results below it: pick one" if found else "") + ")")
        p = found[0].parent
    if p.is_dir() or p.name == "result.json":
        js = p / "result.json" if p.is_dir() else p
        return json.loads(js.read_text())
    if not p.exists():
        raise MissingFile(f"{p} not found")
    load_image(p)  # refuses what is not an image, with the reason
    s = run([p], out / "reconstruction", RunOptions(outfit=outfit), progress=False, log=lambda m: None,
              page=False)
    if s.no_person:
        raise NoPersonFound(f"{p}: no person found")
    if s.failed or s.skipped:
        raise ReconError(f"{p}: {next(iter({**s.failed, **s.skipped}.values()))}")
    key = (s.done or s.unchanged)[0]
    log(f"reconstructed {p} into {out / 'reconstruction' / key}")
    return json.loads((out / "reconstruction" / key / "result.json").read_text())


def animate(source: str | Path, motion: str | Path, out: str | Path, outfit: str | None = None, tightness=None,
            asf: str | Path | None = None, max_seconds: float | None = None, render: str = "mp4",
            size: tuple[int, int] = (480, 640), yaw_deg: float = 20.0, progress: bool = True, log=print,
            dynamics: bool | None = None, garment_model: str | None = None, page: bool = True,
            all_influences: bool = False) -> dict:
    """Animate a reconstructed person; returns {file kind: path}. ``outfit``: an outfit name (default:
    the one ``recon run`` dressed the person in, if any); ``render``: "mp4", "gif" or "none";
    ``dynamics``: the outfit's NCS (swinging cloth) or not (PBNS); None: NCS where it exists;
    ``garment_model``: "pbns" (PBNS / NCS) or "taylor" (the example-based model, quasi-static);
    None: the one ``recon run`` dressed the person with (else pbns); ``page``: with the folder's
    results page (``index.html``, recon.page); ``all_influences``: the .glb keeps every joint
    influence of a vertex (default: the 4 strongest, which engines read)."""
    check_motion(motion)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    person = person_from(source, out, outfit, log)
    body = default_body()
    shape = torch.tensor(list(person["shape"].values()), dtype=torch.float32)
    outfit = outfit or (person.get("outfit") or {}).get("name")
    if tightness is None and person.get("outfit"):
        tightness = person["outfit"].get("tightness")
    if garment_model is None:
        garment_model = (person.get("outfit") or {}).get("garment_model", "pbns")
    m = on_the_ground(load_motion(motion, body, shape, asf), body, shape).first(max_seconds)  # the whole clip's ground
    dresser = Dresser(outfit, dynamics=dynamics, garment_model=garment_model) if outfit else None
    influences = None if all_influences else INFLUENCES
    dressed = None if dresser is None else outfit_animation(body, shape, m.rotmats, m.transl, dresser, m.fps,
                                                           tightness, influences)
    written = {"glb": write_glb(out / "animated.glb", body, shape, m.rotmats, m.transl, m.fps, dressed,
                                animation_name=m.name, influences=influences)}
    if render != "none":
        frames = render_motion(body, shape, m, dresser, tightness, size, yaw_deg, progress)
        written["video"] = write_video(out / f"animated.{render}", frames, m.fps)
    info = {"source": str(source), "motion": m.name, "frames": len(m), "fps": m.fps, "outfit": outfit,
            "garment_model": None if dresser is None else dresser.garment.label,
            "tightness": None if tightness is None else [float(t) for t in tightness],
            "files": {k: v.name for k, v in written.items()}}
    written["json"] = write_json(out / "animation.json", info)
    if page and (index := try_write_page(out, log, kind="animate")):
        written["page"] = index
    return written


def on_the_ground(m: Motion, body: BodyModel, shape: torch.Tensor) -> Motion:
    """The clip moved up or down so that the body's lowest point over the clip is at y = 0 (the
    retargeted root height is the source's, off by the difference in leg and foot geometry)."""
    every = m.rotmats[::5]
    with torch.no_grad():
        low = body(every, shape[None].expand(len(every), -1), transl=m.transl[::5]).vertices[..., 1].min()
    transl = m.transl.clone()
    transl[:, 1] -= low
    return Motion(m.rotmats, transl, m.fps, m.name)


def render_motion(body: BodyModel, shape: torch.Tensor, m: Motion, dresser=None, tightness=None, size=(480, 640),
                  yaw_deg: float = 20.0, progress: bool = True, batch: int = 16, every: int = 1,
                  dressed: DressedOutfit | None = None) -> list[np.ndarray]:
    """Frames of the (dressed) body following the clip, every ``every``-th (the outfit is dressed
    on all of them: NCS needs the motion at its own rate); the camera follows the pelvis on the
    ground plane at a fixed height and distance. ``dressed``: the outfit on every frame already."""
    faces = body.faces.numpy()
    frames = []
    with torch.no_grad():
        bounds = body(m.rotmats[::10], shape[None].expand(len(m.rotmats[::10]), -1), transl=m.transl[::10]).vertices
    height = float((bounds[..., 1].max() - bounds[..., 1].min()).item())
    ground = float(bounds[..., 1].min().item())
    renderer = SequenceRenderer(size=size, yaw_deg=yaw_deg, distance=1.6 * max(height, 1.0) + 0.8)
    # the whole motion at once: NCS carries its state from frame to frame
    if dressed is None and dresser is not None:
        dressed = dresser.animate(body, m.rotmats, shape, m.transl, m.fps, tightness)
    shown = torch.arange(0, len(m), every)
    bar = tqdm(total=len(shown), desc=f"rendering {m.name}", unit="frame", disable=not progress)
    try:
        for s in range(0, len(shown), batch):
            idx = shown[s:s + batch]
            rot, tr = m.rotmats[idx], m.transl[idx]
            with torch.no_grad():
                bv = body(rot, shape[None].expand(len(rot), -1), transl=tr).vertices.numpy()
            for i, f in enumerate(idx.tolist()):
                centre = np.array([tr[i, 0].item(), ground + 0.5 * height, tr[i, 2].item()])
                meshes = [(bv[i], faces, BODY_RGBA)]
                if dressed is not None:
                    meshes.append((dressed.vertices[f], dressed.faces, OUTFIT_RGBA))
                frames.append(renderer(meshes, centre, ground))
                bar.update(1)
    finally:
        renderer.close()
        bar.close()
    return frames


def list_motions() -> str:
    rows = [f"{c['name']:<28} {c['category']:<14} {c['frames'] / FPS:6.1f} s  ({c['split']})" for c in shipped_clips()]
    return "\n".join(["shipped clips (name, category, length, split):", *rows])

