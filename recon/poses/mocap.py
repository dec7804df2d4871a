"""The retargeted mocap pose set: shipped with the package, rebuilt from raw clips on demand.

Every supported clip is parsed (BVH or ASF/AMC), retargeted to the body model's rest
skeleton (recon.poses.retarget), resampled to 30 fps (slerp) and stored in one compact
.npz: local joint rotations as float32 axis-angle (N, 24, 3), pelvis translation (N, 3) and a
clip table. Splits are by CMU subject so that no performer of val/test is seen in training.

The set built from ``../shared/data/mocap`` ships as ``recon/data/poses/mocap-anny-v1.npz``
(sources and licences beside it) and is what every sampler, benchmark and result uses;
``recon poses build`` rebuilds it from the raw clips (``$RECON_SHARED_DIR/data/mocap``) into the
cache, and ``$RECON_POSES`` points recon at another file.
"""
from __future__ import annotations

import csv
import json
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from recon import paths
from recon.body import default_body
from recon.body.base import BodyModel
from recon.errors import MissingFile, ReconError
from recon.poses.asfamc import read_asf_amc
from recon.poses.bvh import read_bvh
from recon.poses.retarget import PRIMARY_CHILD, Retargeter

log = logging.getLogger(__name__)

FPS = 30.0
CACHE_VERSION = 1
# Held-out performers (CMU subject numbers). Salsa partners 60/61 dance the same takes: both train.
SPLIT_SUBJECTS = {"test": {"3", "9", "12", "14"}, "val": {"2", "6", "10"}}
# Formats/skeletons we do not retarget (see README "Poses"): DeepMimic JSON; the Rokoko
# video capture, whose rest pose is not a standing pose.
SKIPPED_SOURCES = {"deepmimic_humanoid3d"}
SKIPPED_PATHS = {"animateddrawings_bvh/rokoko/jesse_dance.bvh"}
POSES_NAME = f"mocap-anny-v{CACHE_VERSION}.npz"
SHIPPED = paths.DATA_DIR / "poses" / POSES_NAME


def split_of(subject: str) -> str:
    for split, subjects in SPLIT_SUBJECTS.items():
        if subject in subjects:
            return split
    return "train"


def resample(rotmats: np.ndarray, transl: np.ndarray, fps_in: float, fps_out: float = FPS):
    """Resample local rotations (slerp) and translations (lerp) to ``fps_out``."""
    f = rotmats.shape[0]
    n_out = max(1, int(np.floor((f - 1) * fps_out / fps_in + 1e-3)) + 1)  # a header's 0.033333 s is 30 fps
    t = np.arange(n_out) * fps_in / fps_out
    i0 = np.minimum(np.floor(t).astype(int), f - 1)
    i1 = np.minimum(i0 + 1, f - 1)
    w = (t - i0)[:, None]
    r0, r1 = rotmats[i0], rotmats[i1]
    rel = Rotation.from_matrix((np.swapaxes(r0, -1, -2) @ r1).reshape(-1, 3, 3)).as_rotvec()
    step = Rotation.from_rotvec(rel * np.repeat(w, rotmats.shape[1], axis=0)).as_matrix()
    out_rot = r0 @ step.reshape(r0.shape)
    out_tr = (1 - w) * transl[i0] + w * transl[i1]
    return out_rot, out_tr


def read_clip(mocap_root: Path, row: dict):
    path = mocap_root / row["path"]
    fps = float(row["true_fps"] or row["header_fps"])
    if row["format"].upper().startswith("ASF"):
        asf = next(path.parent.glob("*.asf"))
        motion = read_asf_amc(asf, path, fps=fps)
    else:
        motion = read_bvh(path, fps=fps)
    if "reference pose" in row.get("note", "") or "daz" in row["source"]:
        motion = motion.subset(np.arange(1, motion.num_frames))  # Daz frame 0 is a T-pose
    return motion


def built_path() -> Path:
    """Where ``recon poses build`` writes a rebuilt set by default (the recon cache)."""
    return paths.cache_dir() / POSES_NAME


def poses_path() -> Path:
    """The pose set in use: $RECON_POSES if set, else the shipped one."""
    return Path(os.environ.get("RECON_POSES", SHIPPED))


def build(body: BodyModel | None = None, mocap_root: Path | None = None, out: Path | None = None,
          limit: int | None = None) -> Path:
    """Retarget every supported clip of ``mocap_root`` (default ``$RECON_SHARED_DIR/data/mocap``;
    clips listed in its ``metadata/clips.csv``) and write the pose set atomically to ``out``
    (default ``built_path()``). Returns its path."""
    mocap_root = Path(mocap_root or paths.shared_dir() / "data" / "mocap")
    table = mocap_root / "metadata" / "clips.csv"
    if not table.exists():
        raise MissingFile(f"{table} not found: the raw clips live in ../shared/data/mocap beside the repository "
                          "(or set RECON_SHARED_DIR); recon ships the retargeted set itself, so only a rebuild "
                          "needs them")
    body = body or default_body()
    with torch.no_grad():
        rest = body()
    rt = Retargeter(rest.joints[0].numpy(), rest.landmarks[0].numpy())
    rows = [r for r in csv.DictReader(open(table)) if r["source"] not in SKIPPED_SOURCES
            and r["path"] not in SKIPPED_PATHS]
    rows = rows[:limit] if limit else rows
    rots, trs, clip_ids, clips = [], [], [], []
    for row in tqdm(rows, desc="retargeting mocap", unit="clip"):
        try:
            motion = read_clip(mocap_root, row)
            res = rt.retarget(motion)
        except (ReconError, ValueError, KeyError, OSError) as e:  # a malformed clip: report it and keep going
            log.warning("skipping %s: %s", row["path"], e)
            continue
        rot, tr = resample(res.rotmats, res.transl, motion.fps)
        primary = [e for k, e in res.errors_deg.items() if PRIMARY_CHILD.get(k.split("->")[0]) == k.split("->")[1]]
        subject = row["cmu_subject"] or Path(row["path"]).parts[0]
        clips.append({
            "name": Path(row["path"]).stem, "path": row["path"], "source": row["source"],
            "subject": subject, "split": split_of(row["cmu_subject"]), "category": row["category"],
            "frames": int(rot.shape[0]), "source_fps": motion.fps,
            "max_primary_bone_error_deg": float(max(e.max() for e in primary)),
        })
        rots.append(Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_rotvec().reshape(-1, 24, 3))
        trs.append(tr)
        clip_ids.append(np.full(rot.shape[0], len(clips) - 1, dtype=np.int32))
    out = Path(out or built_path())
    arrays = dict(rotvec=np.concatenate(rots).astype(np.float32), transl=np.concatenate(trs).astype(np.float32),
                  clip=np.concatenate(clip_ids), clips=np.array(json.dumps(clips)), fps=np.array(FPS))
    paths.atomic_write(out, lambda tmp: np.savez_compressed(open(tmp, "wb"), **arrays))
    return out


@dataclass
class MocapPoses:
    """Retargeted mocap at 30 fps. ``rotvec`` (N, 24, 3), ``transl`` (N, 3), ``clip`` (N,)."""

    rotvec: np.ndarray
    transl: np.ndarray
    clip: np.ndarray
    clips: list[dict]

    @classmethod
    def load(cls, split: str | None = None, path: Path | None = None) -> MocapPoses:
        """The pose set (``path``, else ``poses_path()``), whole or one split."""
        path = Path(path or poses_path())
        if not path.exists():
            raise MissingFile(f"pose set {path} not found: reinstall recon, or rebuild it with `recon poses build`")
        with np.load(path, allow_pickle=False) as z:
            m = cls(z["rotvec"], z["transl"], z["clip"], json.loads(str(z["clips"])))
        return m if split is None else m.split(split)

    def split(self, name: str) -> MocapPoses:
        if name not in ("train", "val", "test"):
            raise ReconError(f"unknown split {name!r}: use train, val or test")
        keep = np.array([c["split"] == name for c in self.clips])
        mask = keep[self.clip]
        return MocapPoses(self.rotvec[mask], self.transl[mask], self.clip[mask], self.clips)

    def __len__(self) -> int:
        return int(self.rotvec.shape[0])
