"""recon animate: motions (files, shipped clips), the animated .glb and the render."""
import json

import numpy as np
import pytest
import roma
import torch
from conftest import MOCAP_CLIPS
from gltf_check import assert_valid, pose_meshes
from PIL import Image

from recon.animate import animate, clip_name, load_motion, on_the_ground
from recon.body import skeleton
from recon.cli import main
from recon.errors import ReconError
from recon.export.bvh import write_bvh
from recon.keypoints import available as mediapipe_available
from recon.poses.bvh import read_bvh
from recon.poses.mocap import MocapPoses

BVH = MOCAP_CLIPS / "cmu_bvh_3dsmax_bvh11" / "131" / "131_01.bvh"
AMC = MOCAP_CLIPS / "cmu_asfamc_cyun9601" / "subjects" / "02" / "02_01.amc"


def test_bvh_is_retargeted_and_resampled_to_30_fps(body):
    src = read_bvh(BVH)
    m = load_motion(BVH, body, body.mean_shape)
    assert m.fps == 30.0 and m.rotmats.shape[1:] == (24, 3, 3) and m.transl.shape == (len(m), 3)
    assert len(m) == int(np.floor((src.num_frames - 1) * 30.0 / src.fps + 1e-3)) + 1
    assert torch.allclose(m.rotmats @ m.rotmats.transpose(-1, -2), torch.eye(3).expand_as(m.rotmats), atol=1e-4)
    with torch.no_grad():
        feet = body(m.rotmats, body.mean_shape[None].expand(len(m), -1), transl=m.transl).joints[:, [7, 8], 1]
    assert 0.5 < m.transl[:, 1].mean() < 1.3 and feet.min() > -0.2  # metres, pelvis above the feet, +Y up


def test_amc_finds_its_asf_or_asks_for_it(body, tmp_path):
    m = load_motion(AMC, body, body.mean_shape)
    assert len(m) > 10
    lone = tmp_path / "02_01.amc"
    lone.write_bytes(AMC.read_bytes())
    with pytest.raises(ReconError, match="--asf"):
        load_motion(lone, body, body.mean_shape)
    assert len(load_motion(lone, body, body.mean_shape, asf=AMC.parent / "02.asf")) == len(m)


def test_recons_own_bvh_round_trips(body, tmp_path):
    """A BVH on recon's skeleton (recon run's pose.bvh) is read back without retargeting."""
    torch.manual_seed(0)
    rot = roma.rotvec_to_rotmat(0.4 * torch.randn(4, 24, 3))
    root = np.array([[0.0, 0.9, 0.0], [0.1, 0.9, 0.1], [0.2, 0.95, 0.2], [0.3, 0.9, 0.3]])
    with torch.no_grad():
        rest = body().joints[0].numpy()
    path = write_bvh(tmp_path / "mine.bvh", list(skeleton.JOINT_NAMES), list(skeleton.JOINT_PARENTS), rest,
                     rot.numpy(), root, fps=30.0)
    m = load_motion(path, body, body.mean_shape)
    assert torch.allclose(m.rotmats, rot, atol=1e-4)
    np.testing.assert_allclose(m.transl.numpy(), root, atol=1e-5)


def test_unsupported_skeleton_is_refused(body, tmp_path):
    names = [f"bone{k}" for k in range(24)]
    path = write_bvh(tmp_path / "odd.bvh", names, list(skeleton.JOINT_PARENTS), np.random.rand(24, 3),
                     np.tile(np.eye(3), (2, 24, 1, 1)), np.zeros((2, 3)))
    with pytest.raises(ReconError, match="unsupported source skeleton"):
        load_motion(path, body, body.mean_shape)


def test_shipped_clips_by_name_and_category(body):
    m = MocapPoses.load()
    assert clip_name("03_01", m.clips) == "03_01"
    walk = clip_name("walk", m.clips)
    assert next(c for c in m.clips if c["name"] == walk)["split"] == "test"  # held out first
    with pytest.raises(ReconError, match="did you mean: 03_01"):
        clip_name("03_0", m.clips)
    small, tall = body.mean_shape.clone(), body.mean_shape.clone()
    h = body.shape_names.index("height")
    small[h], tall[h] = 0.1, 0.9
    a, b = load_motion("walk", body, small), load_motion("walk", body, tall)
    assert torch.equal(a.rotmats, b.rotmats)
    assert b.transl[:, 1].mean() > 1.1 * a.transl[:, 1].mean()  # the root's path follows the legs


def test_animate_a_result_folder(body, tmp_path):
    """From a `recon run` result.json: the .glb is valid and poses the body as the model does at
    every frame, the video has one frame per pose, animation.json records the run."""
    shape = body.mean_shape.clone()
    shape[body.shape_names.index("weight")] = 0.8
    res = tmp_path / "res"
    res.mkdir()
    (res / "result.json").write_text(json.dumps({"shape": dict(zip(body.shape_names, shape.tolist())),
                                                 "outfit": {"name": "top-shorts", "tightness": None}}))
    w = animate(res, "walk", tmp_path / "anim", max_seconds=0.3, render="gif", size=(96, 128), progress=False,
                all_influences=True)
    info = json.loads(w["json"].read_text())
    assert info["outfit"] == "top-shorts" and info["frames"] == 9
    assert info["motion"] == clip_name("walk", MocapPoses.load().clips)
    assert Image.open(w["video"]).n_frames == 9
    assert_valid(w["glb"])
    m = on_the_ground(load_motion("walk", body, shape), body, shape)
    for frame in (0, 8):
        posed = pose_meshes(w["glb"], frame)
        with torch.no_grad():
            ref = body(m.rotmats[frame:frame + 1], shape[None], transl=m.transl[frame:frame + 1]).vertices[0].numpy()
        assert np.abs(posed["body"] - ref).max() < 1e-4
        assert "outfit" in posed
        assert posed["body"][:, 1].min() > -0.03  # standing on the ground, not in it
    with torch.no_grad():
        low = body(m.rotmats[::5], shape[None].expand(len(m.rotmats[::5]), -1), transl=m.transl[::5]).vertices
    assert float(low[..., 1].min()) == pytest.approx(0.0, abs=1e-5)  # the clip's lowest point on the ground


def test_animate_refuses_before_working(tmp_path):
    with pytest.raises(ReconError, match="no motion"):
        animate(tmp_path, "no-such-clip", tmp_path / "out")
    assert not (tmp_path / "out").exists()
    with pytest.raises(ReconError, match="not a `recon run` result folder"):
        animate(tmp_path, "walk", tmp_path / "out")


@pytest.mark.skipif(not mediapipe_available(), reason="needs mediapipe (scripts/setup.sh)")
def test_animating_a_photo_without_a_person_says_so_once(tmp_path, capsys):
    """One line naming the photo once, exit 2, and no animation written."""
    Image.fromarray(np.full((200, 200, 3), 127, np.uint8)).save(tmp_path / "empty.png")
    assert main(["animate", str(tmp_path / "empty.png"), "--motion", "walk", "--out", str(tmp_path / "o"),
                 "--render", "none"]) == 2
    err = capsys.readouterr().err
    assert err.count(str(tmp_path / "empty.png")) == 1 and "no person found" in err and err.count("\n") == 1
    assert not (tmp_path / "o" / "animated.glb").exists()
