"""Mocap readers, retargeting accuracy, resampling and the shipped pose set, which the code must
reproduce from raw clips (short excerpts in tests/data/mocap: the tests never read ../shared)."""
import csv
import json

import numpy as np
import pytest
import torch
from conftest import MOCAP_CLIPS
from scipy.spatial.transform import Rotation

from recon.body import skeleton
from recon.errors import ReconError
from recon.poses.asfamc import read_asf_amc
from recon.poses.bvh import BVHError, read_bvh
from recon.poses.mocap import SPLIT_SUBJECTS, MocapPoses, build, read_clip, resample
from recon.poses.retarget import PRIMARY_CHILD, SKELETON_MAPS, Retargeter, detect_skeleton, snap_to_joint

TINY_BVH = """HIERARCHY
ROOT hip
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT arm
  {
    OFFSET 1 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 2 0 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.5
0 0 0 0 0 0 0 0 0
1 2 3 0 0 90 90 0 0
"""


def test_bvh_forward_kinematics_known_answer(tmp_path):
    p = tmp_path / "tiny.bvh"
    p.write_text(TINY_BVH)
    m = read_bvh(p)
    assert m.names == ["hip", "arm", "arm_end"] and m.fps == 2.0
    np.testing.assert_allclose(m.positions[0], [[0, 0, 0], [1, 0, 0], [3, 0, 0]], atol=1e-9)
    # frame 1: root at (1,2,3) turned +90 deg about Y: +X -> -Z; arm turns +90 about Z: +X -> +Y
    np.testing.assert_allclose(m.positions[1, 1], [1, 2, 2], atol=1e-9)
    np.testing.assert_allclose(m.positions[1, 2], [1, 4, 2], atol=1e-9)


def test_bvh_errors(tmp_path):
    p = tmp_path / "bad.bvh"
    p.write_text("hello")
    with pytest.raises(BVHError, match="not a BVH"):
        read_bvh(p)
    p.write_text(TINY_BVH.replace("0 0 0 0 0 0 0 0 0\n", "0 0 0\n"))
    with pytest.raises(BVHError):
        read_bvh(p)


TINY_ASF = """:version 1.10
:units
  length 1
  angle deg
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name thigh
     direction 0 -1 0
     length 2
     axis 0 0 0 XYZ
    dof rx ry rz
  end
:hierarchy
  begin
    root thigh
  end
"""
TINY_AMC = """:FULLY-SPECIFIED
:DEGREES
1
root 0 5 0 0 0 0
thigh 0 0 0
2
root 0 5 0 0 0 0
thigh 90 0 0
"""


def test_asf_amc_known_answer(tmp_path):
    (tmp_path / "s.asf").write_text(TINY_ASF)
    (tmp_path / "s.amc").write_text(TINY_AMC)
    m = read_asf_amc(tmp_path / "s.asf", tmp_path / "s.amc")
    assert m.names == ["root", "thigh", "thigh_end"]
    np.testing.assert_allclose(m.positions[0, 2], [0, 3, 0], atol=1e-9)
    np.testing.assert_allclose(m.positions[1, 2], [0, 5, -2], atol=1e-9)  # +90 about X: -Y -> -Z


def test_resample_120_to_30_is_exact_decimation():
    rng = np.random.default_rng(0)
    rot = Rotation.from_rotvec(rng.normal(size=(121 * 24, 3))).as_matrix().reshape(121, 24, 3, 3)
    tr = rng.normal(size=(121, 3))
    r, t = resample(rot, tr, 120.0)
    assert r.shape[0] == 31
    np.testing.assert_allclose(r, rot[::4], atol=1e-9)
    np.testing.assert_allclose(t, tr[::4], atol=1e-12)
    r, t = resample(rot[:101], tr[:101], 100.0)  # 1 s at 100 fps -> 31 frames, interpolated
    assert r.shape[0] == 31
    np.testing.assert_allclose(t[1], tr[3] + (tr[4] - tr[3]) / 3, atol=1e-9)


CLIPS = [
    ("cmu_asfamc_cyun9601/subjects/02/02_01.amc", "cmu_asf"),
    ("cmu_bvh_daz_ateliercircle/subjects/05/05_01.bvh", "daz"),
    ("cmu_bvh_daz_salsa_beemsoft/60_lead/60_01_scaled.bvh", "daz"),
    ("cmu_bvh_3dsmax_bvh11/131/131_01.bvh", "cmu_bvh"),
    ("animateddrawings_bvh/fair1/dab.bvh", "mixamo"),
]
TOLERANCE_DEG = 0.5


@pytest.mark.parametrize("rel,kind", CLIPS)
def test_retargeted_pose_reproduces_source_bone_directions(body, rel, kind):
    """Pose the body with the retargeted rotations (float32 axis-angle, as cached) and compare
    every primary bone's direction with the source bone's: within TOLERANCE_DEG."""
    row = next(r for r in csv.DictReader(open(MOCAP_CLIPS / "metadata" / "clips.csv")) if r["path"] == rel)
    motion = read_clip(MOCAP_CLIPS, row)
    motion = motion.subset(np.arange(0, min(motion.num_frames, 1200), 7))
    assert detect_skeleton(motion.names) == kind
    rest = body()
    rt = Retargeter(rest.joints[0].numpy(), rest.landmarks[0].numpy())
    res = rt.retarget(motion)
    rotvec = Rotation.from_matrix(res.rotmats.reshape(-1, 3, 3)).as_rotvec().reshape(-1, 24, 3)
    out = body(torch.tensor(rotvec, dtype=torch.float32))
    pts = torch.cat([out.joints, out.landmarks], 1).numpy()
    # Source points in the body frame, with the retargeter's own axis normalisation.
    table = SKELETON_MAPS[kind]
    src = {n: rt._points(motion, s, False)[0] for n, s in table.items()}
    srest = {n: rt._points(motion, s, True)[0] for n, s in table.items()}
    up, left = snap_to_joint(srest["head"] - srest["pelvis"]), snap_to_joint(srest["left_hip"] - srest["right_hip"])
    align = np.stack([left, up, np.cross(left, up)])
    worst = 0.0
    for j, c in PRIMARY_CHILD.items():
        if c not in table or (kind == "daz" and c == "head_top"):
            continue  # Daz has no head end: the eyes give the head's rotation, not a bone
        a, b = skeleton.POINT_NAMES.index(j), skeleton.POINT_NAMES.index(c)
        ours = pts[:, b] - pts[:, a]
        theirs = (src[c] - src[j]) @ align.T
        cos = np.sum(ours * theirs, -1) / np.linalg.norm(ours, axis=-1) / np.linalg.norm(theirs, axis=-1)
        worst = max(worst, float(np.degrees(np.arccos(np.clip(cos, -1, 1))).max()))
    assert worst < TOLERANCE_DEG, f"{rel}: worst bone direction error {worst:.3f} deg"


def test_pose_cache_splits_by_subject(mocap):
    assert len(mocap) > 40_000
    subjects = {s: {c["subject"] for c in mocap.clips if c["split"] == s} for s in ("train", "val", "test")}
    assert not (subjects["train"] & subjects["test"]) and not (subjects["train"] & subjects["val"])
    assert subjects["test"] == mocap_module_test_subjects() and len(mocap.split("test")) > 3000
    assert mocap.rotvec.dtype == np.float32 and mocap.rotvec.shape[1:] == (24, 3)
    assert np.isfinite(mocap.rotvec).all() and np.isfinite(mocap.transl).all()
    assert max(c["max_primary_bone_error_deg"] for c in mocap.clips) < TOLERANCE_DEG
    with pytest.raises(ReconError, match="unknown split"):
        mocap.split("dev")


def mocap_module_test_subjects():
    return SPLIT_SUBJECTS["test"]


def test_unknown_skeleton_is_reported():
    with pytest.raises(ReconError, match="unsupported source skeleton"):
        detect_skeleton(["root", "a", "b"])


def test_building_from_raw_clips_reproduces_the_shipped_pose_set(body, mocap, tmp_path):
    """`recon poses build` on the excerpts: every clip's frames equal the first frames of that
    clip in the shipped set (the shipped set is what this code makes of the raw clips)."""
    out = build(body, MOCAP_CLIPS, tmp_path / "poses.npz")
    built = MocapPoses.load(path=out)
    assert len(built.clips) == len(CLIPS)
    for i, clip in enumerate(built.clips):
        j = next(k for k, c in enumerate(mocap.clips) if c["path"] == clip["path"])
        assert mocap.clips[j]["split"] == clip["split"] and mocap.clips[j]["frames"] > clip["frames"] > 10
        ours, shipped = built.rotvec[built.clip == i], mocap.rotvec[mocap.clip == j][:clip["frames"]]
        np.testing.assert_allclose(ours, shipped, atol=1e-6, err_msg=clip["path"])
        np.testing.assert_allclose(built.transl[built.clip == i], mocap.transl[mocap.clip == j][:clip["frames"]],
                                   atol=1e-6)


def test_building_without_raw_clips_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv("RECON_SHARED_DIR", str(tmp_path))
    with pytest.raises(ReconError, match="ships the retargeted set"):
        build()


def test_recon_poses_points_at_another_pose_set(tmp_path, monkeypatch, mocap):
    np.savez(tmp_path / "p.npz", rotvec=mocap.rotvec[:10], transl=mocap.transl[:10], clip=np.zeros(10, np.int32),
             clips=np.array(json.dumps(mocap.clips[:1])), fps=np.array(30.0))
    monkeypatch.setenv("RECON_POSES", str(tmp_path / "p.npz"))
    assert len(MocapPoses.load()) == 10
