"""``recon garment author``: a clip's garment animation from a few edited keyframes, through the
outfit's intrinsic garment space (recon.garment.author.model).

Workflow: ``recon garment author --outfit tshirt-skirt --motion CLIP --export 40 --out DIR`` writes
the clip dressed with the default material (NCS) and ``DIR/frame_0040.obj``, the outfit at frame 40
in the clip's frame; edit it (Blender: import, sculpt, export keeping the vertex order), then
``--key 40:edited.obj [--key 200:other.obj]`` propagates it: animated .glb (skinning plus morph
targets), .mp4 and ``authoring.json``. The Python API (``Authoring``) re-propagates after every
edit of a keyframe or of the motion and reports its frame rate.
"""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import roma
import torch
import trimesh

from recon.animate import Motion, load_motion, on_the_ground, render_motion
from recon.body import default_body
from recon.body.base import BodyModel
from recon.body.lbs import blend_transforms
from recon.errors import MissingFile, ReconError
from recon.export.glb import BlendAnimation, write_glb, written_weights
from recon.export.media import write_video
from recon.export.mesh import write_mesh
from recon.export.records import write_json
from recon.garment import store
from recon.garment.author.data import teacher_config
from recon.garment.author.model import PELVIS, AuthorModel, Session, clip_inputs, interpolate_latents
from recon.garment.dress import DressedOutfit, Dresser
from recon.garment.integrate import unpose
from recon.garment.ncs.model import smooth_time
from recon.page import try_write_page

KEY_RGB = (230, 120, 20)  # a keyframe's frame in the preview
MORPH_TARGETS = 64  # principal components of the animation's rest-pose displacements in the .glb


def parse_key(spec: str) -> tuple[int, Path]:
    """"FRAME:MESH" -> (frame, path)."""
    frame, sep, path = spec.partition(":")
    if not sep or not frame.strip().isdigit() or not path:
        raise ReconError(f"--key {spec!r}: give FRAME:MESH, e.g. 40:edited.obj")
    if not Path(path).is_file():
        raise MissingFile(f"keyframe mesh {path} not found")
    return int(frame), Path(path)


def read_keyframe(path: Path, n: int) -> torch.Tensor:
    """A keyframe mesh's vertices (n, 3), in the outfit's vertex order."""
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # noqa: BLE001 - trimesh raises many kinds on a bad file
        raise ReconError(f"{path}: not a mesh trimesh can read ({e})") from e
    v = np.asarray(mesh.vertices, np.float32)
    if v.shape != (n, 3):
        raise ReconError(f"{path}: {len(v)} vertices, the outfit has {n}: edit the exported frame without adding "
                         "or removing vertices, and export it keeping the vertex order")
    return torch.from_numpy(v)


class Authoring:
    """Keyframe authoring of one outfit on one motion: ``set_key(frame, vertices)``, ``propagate()``
    -> (T, N, 3); ``set_motion`` after a body-motion edit; ``fps``: the last propagation's rate."""

    def __init__(self, outfit: str, motion: Motion | str | Path, loop: bool = False, fade: int | None = None,
                 body: BodyModel | None = None, max_seconds: float | None = None):
        """``motion``: a clip (``recon.animate.Motion``), or what ``load_motion`` reads (a .bvh, an .amc,
        a shipped clip's name), retargeted to the model's character; its first ``max_seconds``."""
        path = store.author_path(outfit)
        if not path.exists():
            raise MissingFile(f"no authoring model for {outfit} ({path}): run `recon garment train --model author "
                              f"--outfit {outfit}` (simulations, then training; its time: "
                              "recon/garment/weights/MODEL_CARD.md)")
        self.model, self.meta = AuthorModel.load(path)
        self.body = body or default_body()
        self.outfit = outfit
        self.dresser = Dresser(outfit)
        self.pbns = self.dresser.model
        self.shape = self.dresser.shape  # the character the model was trained on (the paper's fixed character)
        if not isinstance(motion, Motion):
            motion = load_motion(motion, self.body, self.shape)
        self.motion = self._prepared(motion.first(max_seconds))
        self.session = Session(self.model, *self._inputs(), loop=loop, fade=fade)

    def _prepared(self, m: Motion) -> Motion:
        """On the ground, smoothed in time as the simulations' motions were (mocap jitter is no motion)."""
        sigma = teacher_config(self.outfit).smooth_motion
        rot = roma.special_procrustes(smooth_time(m.rotmats[None], sigma)[0])
        return on_the_ground(Motion(rot, smooth_time(m.transl[None], sigma)[0], m.fps, m.name), self.body, self.shape)

    def _inputs(self):
        ncs = self.dresser.garment.ncs if self.model.cfg.base == "ncs" else None  # the pbns family's dynamics
        static, yaw, joints = clip_inputs(self.body, self.pbns, self.shape, self.motion.rotmats, self.motion.transl,
                                          ncs)
        self.pelvis = joints[:, PELVIS:PELVIS + 1]
        return static, yaw, joints

    def interpolated(self) -> torch.Tensor:
        """The keyframes' outfits linearly interpolated between them in the character's space (its
        heading, about the pelvis), held beyond the first and last: the keyframe workflow's
        in-betweens with the same keys, (T, N, 3)."""
        frames = sorted(self.session.keys)
        if not frames:
            raise ValueError("no keyframe to interpolate")
        yaw, keys = self.session.yaw, torch.stack([self.session.keys[f] for f in frames])
        char = torch.einsum("kji,knj->kni", yaw[frames], keys - self.pelvis[frames])
        flat = interpolate_latents(char.reshape(len(frames), -1), frames, len(self), self.session.loop)
        return torch.einsum("tij,tnj->tni", yaw, flat.view(len(self), -1, 3)) + self.pelvis

    def __len__(self) -> int:
        return len(self.motion)

    @property
    def fps(self) -> float:
        return self.session.fps

    def set_key(self, frame: int, vertices: torch.Tensor) -> None:
        self.session.set_key(frame, vertices)

    def remove_key(self, frame: int) -> None:
        self.session.remove_key(frame)

    def set_motion(self, motion: Motion) -> None:
        """Another (edited) body motion of the same length: the garment follows it."""
        if len(motion) != len(self.motion):
            raise ReconError(f"the edited motion has {len(motion)} frames, the keyframed one {len(self.motion)}")
        self.motion = self._prepared(motion)
        self.session.set_motion(*self._inputs())

    def material(self) -> torch.Tensor:
        """The keyframes' intrinsic code (K_z,), their mean: a material to carry to another clip."""
        return self.session.latents().mean(0)

    def propagate(self, material: torch.Tensor | None = None) -> torch.Tensor:
        """The outfit on every frame (T, N, 3): from the keyframes, or from another clip's
        ``material`` (no keyframes needed); with no keyframe and no material, NCS's default cloth."""
        if material is not None:
            z = material.reshape(1, -1).expand(len(self), -1)
            return self.session.propagate(latents=z, residuals=bool(self.session.keys))
        if not self.session.keys:
            return torch.from_numpy(self.default())
        return self.session.propagate()

    def default(self) -> np.ndarray:
        """The clip dressed by the outfit's NCS (the default material), (T, N, 3)."""
        m = self.motion
        return self.dresser.animate(self.body, m.rotmats, self.shape, m.transl, m.fps).vertices

    def dressed(self, vertices: torch.Tensor) -> DressedOutfit:
        return DressedOutfit(np.asarray(vertices), self.dresser.model.faces.numpy(), self.dresser.garment_id,
                             self.dresser.names)

    @torch.no_grad()
    def blend_animation(self, vertices: torch.Tensor, targets: int = MORPH_TARGETS,
                        chunk: int = 64) -> tuple[BlendAnimation, float]:
        """The animation as PBNS's skinning (its weights as the .glb holds them) plus morph targets:
        each frame unposed to the rest pose, the displacements' mean and first ``targets``
        principal components. Also the largest distance (m) of the re-skinned result from
        ``vertices``."""
        rest = self.pbns.rest
        weights = written_weights(self.pbns.weights)  # as the .glb's reader skins: its 4 strongest, renormalised
        disp, blends = [], []
        for s in range(0, len(vertices), chunk):
            r, tr = self.motion.rotmats[s:s + chunk], self.motion.transl[s:s + chunk]
            b = blend_transforms(weights, self.body(r, self.shape[None].expand(len(r), -1), transl=tr).transforms)
            disp.append(unpose(b[..., :3], vertices[s:s + chunk] - self.pbns.apply_blend(rest, b), 0.2))
            blends.append(b)
        d = torch.cat(disp).reshape(len(vertices), -1)
        mean = d.mean(0)
        u, sv, vh = torch.linalg.svd(d - mean, full_matrices=False)
        k = min(targets, len(sv))
        codes = torch.cat([torch.ones(len(d), 1), u[:, :k] * sv[:k]], 1)
        basis = torch.cat([mean[None], vh[:k]])
        again = (codes @ basis).view(len(vertices), -1, 3)
        worst = max(float((self.pbns.apply_blend(rest + again[s:s + chunk], b) - vertices[s:s + chunk])
                          .norm(dim=-1).max()) for s, b in zip(range(0, len(vertices), chunk), blends))
        return BlendAnimation(rest, self.dresser.model.faces.numpy(), self.pbns.weights.detach(), basis, codes), worst


def side_by_side(ours: list[np.ndarray], interpolated: list[np.ndarray], keys: list[int]) -> list[np.ndarray]:
    """Each frame: ours | the interpolation, labelled, a keyframe's in a coloured frame."""
    out = []
    for f, (a, b) in enumerate(zip(ours, interpolated, strict=True)):
        tiles = []
        for img, label in ((a, "ours"), (b, "interpolation, same keys")):
            img = np.ascontiguousarray(img)
            cv2.putText(img, label, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (40, 40, 40), 1, cv2.LINE_AA)
            if f in keys:
                cv2.rectangle(img, (1, 1), (img.shape[1] - 2, img.shape[0] - 2), KEY_RGB, 4)
                cv2.putText(img, f"keyframe {f}", (10, img.shape[0] - 14), cv2.FONT_HERSHEY_SIMPLEX, 0.6, KEY_RGB, 2,
                            cv2.LINE_AA)
            tiles.append(img)
        out.append(np.concatenate(tiles, 1))
    return out


def author(outfit: str, motion: str | Path, out: str | Path, keys: list[str] = (), export: list[int] = (),
           loop: bool = False, render: str = "mp4", size: tuple[int, int] = (480, 640),
           max_seconds: float | None = None, progress: bool = True, log=print, page: bool = True) -> dict:
    """The command: keyframes ("FRAME:MESH") propagated over the clip ``motion``; returns {kind: path}.
    With keyframes and a render, also ``authored-preview``: ours beside the keyframes interpolated;
    ``page``: the folder's results page (recon.page)."""
    parsed = [parse_key(k) for k in keys]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    body = default_body()
    a = Authoring(outfit, motion, loop=loop, body=body, max_seconds=max_seconds)
    m = a.motion
    n = a.session.static.shape[1]
    for frame, path in parsed:
        if not 0 <= frame < len(a):
            raise ReconError(f"--key {frame}: the clip {m.name} has frames 0..{len(a) - 1}")
        a.set_key(frame, read_keyframe(path, n))
    vertices = a.propagate()
    written: dict[str, Path] = {}
    faces = a.dresser.model.faces.numpy()
    for frame in export:
        if not 0 <= frame < len(a):
            raise ReconError(f"--export {frame}: the clip {m.name} has frames 0..{len(a) - 1}")
        written[f"frame_{frame}"] = write_mesh(out / f"frame_{frame:04d}.obj", vertices[frame].numpy(), faces)
    anim, worst = a.blend_animation(vertices)
    written["glb"] = write_glb(out / "authored.glb", body, a.shape, m.rotmats, m.transl, m.fps,
                               outfit=anim, animation_name=m.name)
    if render != "none":
        frames = render_motion(body, a.shape, m, size=size, progress=progress, dressed=a.dressed(vertices))
        written["video"] = write_video(out / f"authored.{render}", frames, m.fps)
        if parsed:  # ours beside the keyframe workflow's in-betweens with the same keys
            plain = render_motion(body, a.shape, m, size=size, progress=progress, dressed=a.dressed(a.interpolated()))
            written["preview"] = write_video(out / f"authored-preview.{render}",
                                             side_by_side(frames, plain, sorted(a.session.keys)), m.fps)
    key_error = {str(f): float((vertices[f] - a.session.keys[f]).norm(dim=-1).max()) * 1000 for f, _ in parsed}
    info = {"outfit": outfit, "motion": m.name, "frames": len(a), "fps": m.fps, "loop": loop,
            "keys": {str(f): str(p) for f, p in parsed}, "keyframe_max_error_mm": key_error,
            "source": "keyframes" if parsed else "NCS (no keyframe: the default material)",
            "propagation_frames_per_second": None if not parsed else round(a.fps, 1),
            "glb_max_error_mm": round(worst * 1000, 2), "files": {k: v.name for k, v in written.items()}}
    written["json"] = write_json(out / "authoring.json", info)
    log(json.dumps(info, indent=1))
    if page and (index := try_write_page(out, log, kind="author")):
        written["page"] = index
    return written
