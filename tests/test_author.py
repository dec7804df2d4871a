"""Keyframe authoring in the intrinsic garment space (recon.garment.author.model, author.data,
author.train; recon.garment.author.command): U-block mixing, the motion descriptor, the character-space motion
signature, motion invariance on a toy system, keyframes matched exactly after propagation, the
latent interpolation, the descriptor's start as PCA, friction, and the command's files."""
import json
from dataclasses import asdict, replace

import numpy as np
import pytest
import roma
import torch
import trimesh
from gltf_check import assert_valid, pose_meshes
from PIL import Image

from recon.errors import ReconError
from recon.garment import store
from recon.garment.author import data as author_data
from recon.garment.author import eval as author_eval
from recon.garment.author.command import Authoring, author, parse_key, read_keyframe
from recon.garment.author.curves import probe, render_probe
from recon.garment.author.data import (
    RANGES,
    AuthorDataConfig,
    Intrinsics,
    Sim,
    cycled_chunks,
    fabric,
    plan,
    sample_intrinsics,
    sim_folder,
    teacher_config,
    train_frames,
)
from recon.garment.author.eval import render
from recon.garment.author.model import (
    AuthorConfig,
    AuthorModel,
    IntrinsicAutoencoder,
    MotionEncoder,
    Session,
    ShapeDescriptor,
    UBlock,
    clip_inputs,
    heading,
    interpolate_latents,
    residual_weights,
    signature,
)
from recon.garment.author.train import (
    AuthorTrainConfig,
    Frames,
    hanging_outfit,
    in_chunks,
    is_trained,
    model_name,
    principal_basis,
    train_autoencoder,
    within_variance,
)
from recon.garment.integrate import contact_friction
from recon.garment.ncs.data import Chunk, chunks_of
from recon.garment.ncs.model import NCS, motion_inputs
from recon.garment.pbns.model import PBNS
from recon.page.build import folder_kind

TINY = AuthorConfig(window=3, stride=1, joints=(), shape_dims=6, pca_dims=8, shape_hidden=(16,), motion_hidden=(16,),
                    subnets=3, latent=5, blocks=2)


def tiny_model(index: torch.Tensor, cfg: AuthorConfig = TINY, seed: int = 0) -> AuthorModel:
    torch.manual_seed(seed)
    n = len(index)
    basis, _ = torch.linalg.qr(torch.randn(3 * n, cfg.pca_dims))
    desc = ShapeDescriptor(torch.zeros(3 * n), basis, 0.01, cfg.shape_dims, cfg.shape_hidden)
    ae = IntrinsicAutoencoder((cfg.window + 1) * 72, cfg)
    return AuthorModel(index, desc, ae, "tshirt-skirt", cfg).eval()


def test_ublock_blends_its_subnetworks_linearly():
    torch.manual_seed(0)
    block = UBlock(4, 3, subnets=3, act=False).double()
    x = torch.randn(5, 4, dtype=torch.float64)
    one_hot = torch.eye(3, dtype=torch.float64)
    singles = [block(x, one_hot[i].expand(5, -1)) for i in range(3)]
    for i in range(3):  # a one-hot descriptor is that sub-network's linear map
        assert torch.allclose(singles[i], x @ block.weight[i] + block.bias[i])
    md = torch.tensor([0.2, 0.5, 0.3], dtype=torch.float64).expand(5, -1)
    assert torch.allclose(block(x, md), 0.2 * singles[0] + 0.5 * singles[1] + 0.3 * singles[2])
    assert torch.autograd.gradcheck(lambda a, m: block(a, m), (x.clone().requires_grad_(),
                                                               md.clone().requires_grad_()))


def test_motion_descriptor_is_a_blend():
    torch.manual_seed(0)
    enc = MotionEncoder(12, (8,), 5).eval()
    md = enc(torch.randn(7, 12) * 10)
    assert (md >= 0).all() and torch.allclose(md.sum(-1), torch.ones(7))


def test_signature_is_in_the_character_space_of_each_frame():
    torch.manual_seed(0)
    t, w = 6, 3
    joints = torch.randn(t, 24, 3)
    rot = roma.rotvec_to_rotmat(torch.randn(t, 3) * 0.5)
    sig = signature(joints, heading(rot), w)
    # the whole motion turned about +Y and moved: the same signature
    turn = roma.rotvec_to_rotmat(torch.tensor([0.0, 1.1, 0.0]))
    moved = signature(joints @ turn.T + torch.tensor([2.0, 0.1, -3.0]), heading(turn @ rot), w)
    assert torch.allclose(sig, moved, atol=1e-5)
    # the heading is a turn about +Y: gravity stays -Y in the character space
    assert torch.allclose(heading(rot)[:, 1], torch.tensor([0.0, 1.0, 0.0]).expand(t, -1), atol=1e-6)
    # frame 0's past repeats frame 0; with a loop it comes from the clip's end
    s0 = sig[0].view(w + 1, 24, 3)
    assert torch.allclose(s0[0], s0[-1])
    looped = signature(joints, heading(rot), w, loop=True)[0].view(w + 1, 24, 3)
    rel = joints[t - 1] - joints[0, 0]
    assert torch.allclose(looped[-2], rel @ heading(rot)[0], atol=1e-5)
    # every stride-th past frame and the current one, the joints kept
    strided = signature(joints, heading(rot), 5, stride=2, keep=(0, 4)).view(t, 3, 2, 3)
    full = signature(joints, heading(rot), 5).view(t, 6, 24, 3)
    # (einsum on other shapes may take other float kernels: equal to the last bits, not bit for bit)
    torch.testing.assert_close(strided, full[:, [1, 3, 5]][:, :, [0, 4]], rtol=0, atol=1e-6)


def test_latents_interpolate_between_keyframes_and_hold_beyond():
    z = torch.tensor([[0.0], [10.0], [4.0]])
    out = interpolate_latents(z, [2, 7, 9], 12)[:, 0]
    assert out[:3].tolist() == [0.0, 0.0, 0.0] and out[7] == 10.0 and out[9] == 4.0 and out[11] == 4.0
    assert torch.isclose(out[4], torch.tensor(4.0)) and torch.isclose(out[8], torch.tensor(7.0))
    loop = interpolate_latents(z[[0, 2]], [2, 9], 12, loop=True)[:, 0]  # 9 -> 2 across the end (5 frames)
    assert torch.isclose(loop[11], torch.tensor(4.0 - 4.0 * 2 / 5)) and torch.isclose(loop[0], torch.tensor(1.6))
    w = residual_weights([2, 3, 9], 12, fade=4)
    assert torch.equal(w[[2, 3, 9]], torch.eye(3))  # each key's own residual only, at each key


@pytest.mark.parametrize("loop", [False, True])
def test_keyframes_are_matched_exactly_after_propagation(loop):
    torch.manual_seed(1)
    t, n = 20, 30
    index = torch.arange(5, 25)
    model = tiny_model(index)
    static = torch.randn(t, n, 3)
    yaw = heading(roma.rotvec_to_rotmat(torch.randn(t, 3)))
    session = Session(model, static, yaw, torch.randn(t, 24, 3), loop=loop, fade=6)
    keys = {0: torch.randn(n, 3), 1: torch.randn(n, 3), 12: torch.randn(n, 3)}
    for f, v in keys.items():
        session.set_key(f, v)
    out = session.propagate()
    assert out.shape == (t, n, 3) and np.isfinite(session.fps)
    for f, v in keys.items():
        assert torch.allclose(out[f], v, atol=1e-5)
    free = session.propagate(residuals=False)  # the model alone: the keys' z decoded, not their meshes
    assert not torch.allclose(free[12], keys[12], atol=1e-3)
    assert torch.allclose(free[:, :5], static[:, :5]) and torch.allclose(out[2:6, :5], static[2:6, :5])
    with pytest.raises(ValueError, match="outside"):
        session.set_key(t, keys[0])


def test_the_network_share_goes_from_interpolation_to_the_papers_propagation():
    torch.manual_seed(2)
    t, n = 16, 30
    index = torch.arange(5, 25)
    static = torch.randn(t, n, 3)
    yaw = heading(roma.rotvec_to_rotmat(torch.randn(t, 3)))
    keys = {2: torch.randn(n, 3), 13: torch.randn(n, 3)}
    out = {}
    for share in (0.0, 0.5, 1.0):
        session = Session(tiny_model(index, replace(TINY, network_share=share)), static, yaw, torch.randn(t, 24, 3))
        for f, v in keys.items():
            session.set_key(f, v)
        out[share] = session.propagate()
        for f, v in keys.items():  # every share matches the keyframes
            assert torch.allclose(out[share][f], v, atol=1e-5)
    frames, offsets = session.key_offsets()
    interp = static + torch.einsum("tij,tnj->tni", yaw, interpolate_latents(offsets.reshape(2, -1), frames, t)
                                   .view(t, n, 3))
    assert torch.allclose(out[0.0], interp, atol=1e-5)  # none of the network: the offsets interpolated
    assert torch.allclose(out[0.5], (out[0.0] + out[1.0]) / 2, atol=1e-5)
    assert not torch.allclose(out[1.0], interp, atol=1e-3)


@pytest.mark.slow
def test_the_ncs_base_is_ncs_on_the_whole_motion_in_chunks(body):
    """clip_inputs' NCS cloth, posed 64 frames at a time, is NCS run on the whole sequence at
    once, on the character's own (unresized) outfit; and it moves unlike PBNS's drape."""
    pbns, ck = PBNS.load(store.trained_pbns("tshirt-skirt"))
    ncs, _ = NCS.load(store.ncs_path("tshirt-skirt"))
    torch.manual_seed(3)
    t = 70
    rot = roma.rotvec_to_rotmat(torch.randn(t, 24, 3) * 0.1 + torch.linspace(0, 1, t)[:, None, None])
    transl = torch.linspace(0, 0.6, t)[:, None] * torch.tensor([[0.0, 0.0, 1.0]])
    base, _, _ = clip_inputs(body, pbns, ck["shape"], rot, transl, ncs)
    want, _ = ncs.animate(*motion_inputs(body, rot, ck["shape"], transl, 30.0))
    assert base.shape == want.shape and torch.allclose(base, want, atol=1e-5)
    static = clip_inputs(body, pbns, ck["shape"], rot, transl)[0]
    assert (base - static).norm(dim=-1).mean() > 1e-3


def test_descriptor_starts_as_pca_and_the_model_survives_save_load(tmp_path):
    torch.manual_seed(0)
    x = torch.randn(40, 3) @ torch.randn(3, 60) * 0.01 + 0.001 * torch.randn(40, 60)
    offsets = x.view(40, 20, 3)
    mean, basis, scale = principal_basis(offsets, 8)
    desc = ShapeDescriptor(mean, basis, scale, 3, (16,)).eval()
    pca3 = ((offsets.reshape(40, -1) - mean) @ basis[:, :3]) @ basis[:, :3].T + mean
    with torch.no_grad():
        got = desc.decode(desc.encode(offsets)).reshape(40, -1)
    # the nonlinear paths start small: PCA's reconstruction to within 2 % of the data's spread
    assert (got - pca3).norm() < 0.02 * (offsets.reshape(40, -1) - mean).norm()
    model = tiny_model(torch.arange(20))
    path = model.save(tmp_path / "m.pt", {"seconds": {}})
    loaded, meta = AuthorModel.load(path)
    sig = torch.randn(4, (TINY.window + 1) * 72)
    off = torch.randn(4, 20, 3) * 0.01
    z = model.latent(off, sig)
    assert torch.allclose(loaded.latent(off, sig), z, atol=2e-2, rtol=2e-2)  # float16 storage
    assert torch.allclose(loaded.offsets(z, sig), model.offsets(z, sig), atol=1e-4)
    cfg = replace(TINY, architecture="concat")  # the ablation's networks come back as saved
    concat = AuthorModel(model.index, model.descriptor, IntrinsicAutoencoder(sig.shape[1], cfg), "x", cfg).eval()
    again, _ = AuthorModel.load(concat.save(tmp_path / "c.pt", {}))
    assert again.cfg.architecture == "concat"
    assert torch.allclose(again.latent(off, sig), concat.latent(off, sig), atol=2e-2, rtol=2e-2)
    blob = torch.load(path, weights_only=True)
    for k in ("base", "network_share"):  # a file from before these options: what it was made with
        del blob["config"][k]
    torch.save(blob, tmp_path / "old.pt")
    assert (AuthorModel.load(tmp_path / "old.pt")[0].cfg.base, AuthorModel.load(tmp_path / "old.pt")[0].cfg
            .network_share) == ("pbns", 1.0)
    assert loaded.cfg.base == "ncs" and loaded.cfg.network_share == TINY.network_share


def toy_cloth(theta: torch.Tensor, motion: torch.Tensor) -> torch.Tensor:
    """A 'cloth' descriptor, nonlinear in 2 intrinsic parameters and a 2-D motion."""
    return torch.stack([theta[:, 0] * torch.sin(motion[:, 0]), theta[:, 1] * motion[:, 1], theta[:, 0] * theta[:, 1],
                        (1 + theta[:, 0]) * torch.cos(motion[:, 1])], 1)


def test_the_encoding_learns_motion_invariance_on_a_toy_system():
    """After training, z of one frame decoded on the other motions of its parameter set lands far
    closer than the same motions under a neighbouring parameter set, and z hardly varies within a
    set (the motion enters only through the U-blocks' blend)."""
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(0)
    sets, per = 24, 40
    theta = torch.rand(sets, 2, generator=g)
    motion = torch.randn(sets * per, 2, generator=g)
    s = toy_cloth(theta.repeat_interleave(per, 0), motion)
    set_id = torch.arange(sets).repeat_interleave(per)
    frames = Frames(s, motion, set_id, theta.repeat_interleave(per, 0), set_id, torch.zeros_like(set_id))
    cfg = AuthorTrainConfig(model=AuthorConfig(shape_dims=4, motion_hidden=(32,), subnets=8, latent=4, blocks=3,
                                               lam=1.0), steps=600, groups=6, frames=12, lr=1e-2)
    ae = train_autoencoder(s, motion, frames, cfg, log=lambda *_: None)
    with torch.no_grad():
        md = ae.motion_descriptor(motion)
        z = ae.encode(s, md)
        cross = ae.decode(z[torch.arange(sets) * per].repeat_interleave(per, 0), md)  # one frame's z per set
    err = (cross - s).pow(2).sum(1).mean()
    other = (toy_cloth(theta.roll(1, 0).repeat_interleave(per, 0), motion) - s).pow(2).sum(1).mean()
    assert err < 0.5 * other
    assert within_variance(z, sets) < 0.05


def test_friction_slows_touching_cloth_along_the_surface_only():
    body_v = torch.tensor([[x, 0.0, z] for x in np.linspace(-1, 1, 11) for z in np.linspace(-1, 1, 11)])
    body_n = torch.tensor([0.0, 1.0, 0.0]).expand(len(body_v), -1)
    prev = torch.tensor([[0.05, 0.004, 0.0], [0.05, 0.2, 0.0]])  # touching, far
    step = torch.tensor([0.01, -0.002, 0.005])
    proj = contact_friction(prev + step, prev, body_v, body_n, eps=0.004, friction=0.5)
    assert torch.allclose(proj[0] - prev[0], torch.tensor([0.005, -0.002, 0.0025]))
    assert torch.equal(proj[1], prev[1] + step)


def test_intrinsics_span_their_ranges_and_scale_the_fabric():
    ps = sample_intrinsics(16, seed=0)
    u = np.stack([p.vector() for p in ps])
    assert (u >= 0).all() and (u <= 1).all()
    assert (np.sort(u, 0)[0] < 1 / 16 + 1e-3).all() and (np.sort(u, 0)[-1] > 15 / 16 - 1e-3).all()  # a hypercube
    base = teacher_config("tshirt-skirt")
    f = fabric(base, Intrinsics(stretch=2.0, bend=0.5, mass=1.5, gravity=0.8, damping=0.9))
    assert f.edge.weight == 2.0 * base.edge.weight and f.bend.weight == 0.5 * base.bend.weight
    assert np.isclose(f.gravity.weight, base.gravity.weight * 1.2) and np.isclose(f.inertia.weight,
                                                                                   base.inertia.weight * 1.5)
    assert f.inertia.keep_velocity == 0.9 and Intrinsics() == Intrinsics(**{k: getattr(Intrinsics(), k)
                                                                          for k in RANGES})


def test_key_arguments_are_checked(tmp_path):
    mesh = tmp_path / "k.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert parse_key(f"12:{mesh}") == (12, mesh)
    for bad in ("12", f"x:{mesh}", "3:missing.obj"):
        with pytest.raises(ReconError):
            parse_key(bad)
    with pytest.raises(ReconError, match="3 vertices, the outfit has 5"):
        read_keyframe(mesh, 5)


@pytest.mark.slow
def test_author_command_matches_its_keys_and_writes_a_valid_glb(body, tmp_path, monkeypatch):
    monkeypatch.setenv("RECON_CACHE_DIR", str(tmp_path / "cache"))
    with pytest.raises(Exception, match="recon garment train --model author"):
        author("tshirt-skirt", "walk", tmp_path / "none", render="none", max_seconds=0.3)
    model = tiny_model(hanging_outfit(body, "tshirt-skirt").index)
    model.save(store.author_path("tshirt-skirt"), {"seconds": {}})
    first = author("tshirt-skirt", "walk", tmp_path / "a", export=[4], render="none", max_seconds=0.4)
    key = trimesh.load(first["frame_4"], process=False)
    edited = tmp_path / "edited.obj"
    v = np.asarray(key.vertices).copy()
    v[model.index.numpy(), 1] += 0.03  # the skirt lifted 3 cm
    trimesh.Trimesh(v, key.faces, process=False).export(edited)
    out = author("tshirt-skirt", "walk", tmp_path / "b", keys=[f"4:{edited}"], render="gif", max_seconds=0.4,
                 size=(64, 48), progress=False)
    info = json.loads(out["json"].read_text())
    assert info["keyframe_max_error_mm"]["4"] < 0.01 and info["propagation_frames_per_second"] > 0
    assert out["video"].exists()
    assert_valid(out["glb"])
    posed = pose_meshes(out["glb"], frame=4)["outfit"]
    assert np.abs(posed - v).max() < info["glb_max_error_mm"] / 1000 + 1e-3
    # the preview: ours beside the interpolation with the same keys, and the folder's page card
    video, preview = Image.open(out["video"]), Image.open(out["preview"])
    assert preview.size == (2 * video.size[0], video.size[1]) and preview.n_frames == video.n_frames
    assert folder_kind(tmp_path / "b") == "author" and out["page"].is_file()
    assert "authored-preview.gif" in (tmp_path / "b" / ".recon-page" / "data.js").read_text()
    a = Authoring("tshirt-skirt", "walk", body=body, max_seconds=0.4)
    a.set_key(2, torch.from_numpy(v).float())
    a.set_key(9, torch.from_numpy(np.asarray(key.vertices)).float())
    between = a.interpolated()
    assert torch.allclose(between[2], a.session.keys[2], atol=1e-5)
    assert torch.allclose(between[9], a.session.keys[9], atol=1e-5)
    char = lambda f, x: (x - a.pelvis[f]) @ a.session.yaw[f]  # noqa: E731 - the character's space at frame f
    want = (4 / 7) * char(2, a.session.keys[2]) + (3 / 7) * char(9, a.session.keys[9])  # frame 5 of 2..9
    assert torch.allclose(char(5, between[5]), want, atol=1e-5)
    assert torch.allclose(char(0, between[0]), char(2, a.session.keys[2]), atol=1e-5)  # held before the first


def test_the_train_data_only_grows_with_its_set_count():
    small, big = AuthorDataConfig(train_sets=3), AuthorDataConfig(train_sets=5)
    assert sim_folder(small) == sim_folder(big)  # the same simulations: the count adds, changes none
    a, b = plan(small), plan(big)
    assert b[:len(a)] == a and len(b) - len(a) == 2 * small.train_chunks
    assert [s.split for s in a][:2] == ["val", "val"] and a[-1].split == "train"  # held-out data first
    train = [s for s in b if s.split == "train"]
    assert [s.set for s in train] == [k // big.train_chunks for k in range(len(train))]
    assert len({s.params for s in train}) == 5 and len({s.name for s in train}) == len(train)
    assert train_frames(big) == 5 * big.train_chunks * (big.chunk - big.lead)
    assert sample_intrinsics(3, 0, extendable=True) == sample_intrinsics(5, 0, extendable=True)[:3]
    assert sample_intrinsics(3, 0) != sample_intrinsics(5, 0)[:3]  # a Latin hypercube is redrawn whole
    u = np.stack([p.vector() for p in sample_intrinsics(64, 0, extendable=True)])
    assert u.min() >= 0 and u.max() <= 1 and (u.max(0) - u.min(0) > 0.9).all()


def test_train_sets_can_share_their_motions_in_one_simulation_folder():
    own, shared = AuthorDataConfig(train_sets=6), AuthorDataConfig(train_sets=6, motion_share=3)
    assert sim_folder(own) == sim_folder(shared)  # which simulations, not what a simulation is
    chunks = {}
    for s in plan(shared):
        if s.split == "train":
            chunks.setdefault(s.set, []).append(s.chunk)
    assert chunks[0] == chunks[1] == chunks[2] != chunks[3] == chunks[4] == chunks[5]
    assert len(chunks[0]) == shared.train_chunks and train_frames(shared) == train_frames(own)
    mine = {s.set: s.chunk for s in plan(own) if s.split == "train"}
    assert len(set(mine.values())) == 6  # the default: every set its own chunks
    assert [s for s in plan(shared) if s.split != "train"] == [s for s in plan(own) if s.split != "train"]


def test_train_chunks_start_again_when_the_clips_run_out():
    everything = chunks_of("val", 200, 10 ** 6, 0)
    n = len(everything)
    more = cycled_chunks("val", 200, 2 * n + 3, 0)
    assert more[:n] == everything and len(more) == 2 * n + 3
    assert sorted(more[n:2 * n]) == sorted(everything) and more[n:2 * n] != everything  # reshuffled
    assert cycled_chunks("val", 200, n + 1, 0) == more[:n + 1]


def test_models_of_a_set_count_are_named_and_kept_when_up_to_date(tmp_path, monkeypatch):
    assert model_name("dress") == "dress" and model_name("dress", "concat") == "dress-concat"
    assert model_name("dress", "ours", AuthorDataConfig.train_sets) == "dress"
    assert model_name("dress", "ours", 143) == "dress-143sets"
    monkeypatch.setattr(store, "author_path", lambda name: tmp_path / f"author_{name}.pt")
    cfg = AuthorTrainConfig(data=AuthorDataConfig(train_sets=143, workers=2))
    assert not is_trained(cfg)
    meta = {"config": asdict(cfg), "data_folder": sim_folder(cfg.data).name}  # as train() saves it: tuples
    tiny_model(torch.arange(20)).save(store.author_path("tshirt-skirt-143sets"), meta)
    assert is_trained(cfg) and is_trained(replace(cfg, data=replace(cfg.data, workers=1)))
    assert not is_trained(replace(cfg, steps=10))  # another recipe: trained again


def fake_report(outfit: str = "tshirt-skirt") -> dict:
    """An outfit's results as ``author.eval.evaluate`` returns them, with made-up numbers."""
    ratios = {r: {"ours": 10.0 + i, "interpolation: vertices": 20.0 - 4 * i} for i, r in
              enumerate(("0.01", "0.02", "0.05", "0.1", "0.2"))}
    inv = {"ours": {"descriptor_mm": 1.0, "same_motion_mm": 2.0, "cross_motion_mm": 3.0}}
    return {"outfit": outfit, "split": "test", "frames": {"train": 4480, "test": 2160},
            "sets": {"train": 32, "test": 4}, "windows": 3, "lead": 20, "vertices": 10, "train_seconds": {},
            "data_seconds": None,
            "speed": {"frames": 300, "threads": 1, "key_edit_fps": 900.0, "motion_edit_fps": 200.0},
            "propagation": {"ratios": ratios, "keys": {r: 2 for r in ratios}, "material_from_other_clip_mm": None},
            "curve": {"rows": [{"sets": 32, "frames": 4480, "ours_mm": {r: v["ours"] for r, v in ratios.items()}}],
                      "absent": [143, 715]},
            "invariance": inv, "previous_ablations": {"data": "old plan", "invariance": inv, "descriptor": []}}


def test_the_report_states_the_claim_the_curve_and_old_ablations():
    r = fake_report()
    ratios = r["propagation"]["ratios"]
    text = render([r])
    assert "ours 11.0 mm against 4.0 mm, not met" in text
    assert "| 32 " in text and "Not trained yet: 143, 715 sets" in text
    assert "Ablations not re-run in this report: old plan" in text
    ratios["0.02"]["ours"] = 3.0
    assert "ours 3.0 mm against 4.0 mm, met" in render([r])


class FakeSimulator:
    """The data job's worker without the simulation: zero offsets of the run's shape."""

    def __init__(self, outfit, settle):
        pass

    def __call__(self, sim):
        return np.zeros((sim.chunk.frames + 1, 2, 3), np.float16)


def stopped_after(n: int):
    """A tqdm that lets ``n`` runs finish, then the user presses Ctrl-C."""
    def progress(it, **kw):
        for i, x in enumerate(it):
            if i == n:
                raise KeyboardInterrupt
            yield x
    return progress


def test_the_data_job_is_stopped_and_continued_keeping_its_runs_and_time(tmp_path, monkeypatch):
    monkeypatch.setenv("RECON_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(author_data, "Simulator", FakeSimulator)
    cfg = AuthorDataConfig(train_sets=3, val_sets=1, val_windows=1, test_sets=1, test_windows=1, window=30,
                           workers=1)  # in this process: the fake worker
    folder, sims = sim_folder(cfg), plan(cfg)
    monkeypatch.setattr(author_data, "tqdm", stopped_after(2))
    with pytest.raises(KeyboardInterrupt):
        author_data.generate(cfg, log=lambda *a: None)
    assert len(author_data.missing(folder, sims)) == len(sims) - 2  # the finished runs are kept
    spent = json.loads((folder / "timing.json").read_text())["seconds"]
    assert spent > 0
    monkeypatch.setattr(author_data, "tqdm", stopped_after(len(sims)))
    assert author_data.generate(cfg, log=lambda *a: None) == folder
    assert not author_data.missing(folder, sims)
    after = json.loads((folder / "timing.json").read_text())["seconds"]
    assert after > spent
    author_data.generate(cfg, log=lambda *a: None)  # nothing left to do: no time added
    assert json.loads((folder / "timing.json").read_text())["seconds"] == after


def test_update_keeps_the_other_outfits_tables(monkeypatch, tmp_path):
    runs = []
    monkeypatch.setattr(author_eval, "evaluate", lambda o, split, ablations, log: runs.append(o) or fake_report(o))
    author_eval.evaluate_and_report(["tshirt-skirt", "dress"], out_dir=tmp_path, ablations=False)
    path = tmp_path / "garment-author.json"
    first = json.loads(path.read_text())["outfits"]
    monkeypatch.setattr(author_eval, "evaluate", lambda o, split, ablations, log: {**fake_report(o), "windows": 9})
    author_eval.evaluate_and_report(["dress"], out_dir=tmp_path, ablations=False, update=True)
    kept = json.loads(path.read_text())["outfits"]
    assert [r["outfit"] for r in kept] == ["tshirt-skirt", "dress"]
    assert kept[0] == first[0] and kept[1]["windows"] == 9
    author_eval.evaluate_and_report(["dress"], out_dir=tmp_path, ablations=False)
    assert [r["outfit"] for r in json.loads(path.read_text())["outfits"]] == ["dress"]


def test_principal_basis_of_many_frames_from_a_subset_and_in_half_precision():
    torch.manual_seed(0)
    x = (torch.randn(60, 3, dtype=torch.float64) @ torch.randn(3, 30, dtype=torch.float64) * 0.01).view(60, 10, 3)
    mean, basis, scale = principal_basis(x.float(), 3)
    m2, b2, s2 = principal_basis(x.half(), 3, max_frames=12)  # every 5th frame, the files' precision
    assert torch.allclose(basis @ basis.T, b2 @ b2.T, atol=1e-3)  # the same subspace
    assert abs(scale - s2) < 1e-3 * scale and torch.allclose(mean, m2, atol=3e-5)
    c = in_chunks(lambda a: a.reshape(len(a), -1) @ basis, x.half(), size=7)  # rows in chunks, as float32
    assert c.dtype == torch.float32 and torch.allclose(c, x.float().reshape(60, -1) @ basis, atol=1e-4)


class _ProbeModel:
    """A stand-in for an authoring model: its latent is a linear image of the parameters that the
    first two cloth vertices carry (``knows``), or noise; its decoder ignores the latent."""

    def __init__(self, knows: bool):
        self.knows, self.mix = knows, torch.randn(6, 10, generator=torch.Generator().manual_seed(1))
        self.descriptor = self

    def latent(self, offsets, sig):
        theta = offsets[:, :2].reshape(len(offsets), 6)
        noise = 0.05 * sig[:, :10]
        return theta @ self.mix + noise if self.knows else sig[:, :10]

    def encode(self, offsets):
        return offsets.reshape(len(offsets), -1)

    def offsets(self, z, sig):
        return torch.zeros(len(z), 4, 3)


def _probe_frames(sets: int, windows: int, seed: int, first_set: int = 0):
    """Frames of ``sets`` parameter sets x ``windows`` motions (20 frames each): the cloth's first two
    vertices hold the set's parameters, the rest moves with the window's motion."""
    g = torch.Generator().manual_seed(seed)
    theta = torch.rand(sets, 6, generator=g)
    motion = torch.randn(windows, 20, 16, generator=g)
    parts, sims = [], []
    for s in range(sets):
        for w in range(windows):
            off = torch.zeros(20, 4, 3)
            off[:, :2] = theta[s].view(2, 3)
            off[:, 2:] = motion[w, :, :6].view(20, 2, 3)
            parts.append((off, motion[w], torch.full((20,), first_set + s), theta[s].expand(20, -1),
                          torch.full((20,), len(sims)), torch.arange(20)))
            sims.append(Sim("test", first_set + s, Chunk("test", w, 0, 20), None))
    return Frames(*[torch.cat(c) for c in zip(*parts)]), sims


def test_the_probe_tells_a_latent_that_knows_the_parameters_from_one_that_does_not():
    torch.manual_seed(0)
    train_f, _ = _probe_frames(24, 2, seed=2)
    test_f, sims = _probe_frames(6, 3, seed=3, first_set=2000)
    knows = probe(_ProbeModel(True), train_f, test_f, sims)
    blind = probe(_ProbeModel(False), train_f, test_f, sims)
    for r in (knows, blind):  # the cloth itself carries the parameters: the descriptor's probe finds them
        assert np.mean(r["features"]["descriptor S"]["test_sims_r2"]) > 0.95
    assert np.mean(knows["features"]["latent z"]["test_sims_r2"]) > 0.95
    assert np.mean(knows["features"]["latent z"]["train_sets_held_out_r2"]) > 0.95
    assert np.mean(blind["features"]["latent z"]["test_sims_r2"]) < 0.2
    assert knows["spread"]["test"]["ratio"] < 0.05 < blind["spread"]["test"]["ratio"]
    g = knows["signal"]
    assert g["pairs"] == 3 * 15 and g["between_sets_mm"] > 100 and g["decoded_between_sets_mm"] == 0.0
    text = "\n".join(render_probe(knows))
    assert "### What the latent knows" in text and "| latent z" in text and "learning curve" not in text
    curve = "\n".join(render_probe(knows, None, {"32": blind, "8": knows}))
    assert curve.index("| 8 ") < curve.index("| 32 ")  # by train sets
