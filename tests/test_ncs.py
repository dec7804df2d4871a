"""Neural Cloth Simulation (thesis ch. 6): descriptors, the bias-free dynamic branch, inertia."""
import json
from dataclasses import replace

import numpy as np
import pytest
import roma
import torch
import trimesh
from gltf_check import assert_valid, pose_meshes

from recon.body import skeleton
from recon.body.lbs import forward_kinematics
from recon.garment import losses as L
from recon.garment import ncs, store
from recon.garment.data import trained_outfit
from recon.garment.dress import Dresser
from recon.garment.evaluate_ncs import _clip, hem_vertices
from recon.garment.gltf import write_glb
from recon.garment.ncs_train import (
    MotionWindows,
    NCSTrainConfig,
    Step,
    distil_static,
    hanging_part_to_train,
    param_groups,
    part_outfit,
    train,
)
from recon.garment.pbns import PBNS, initial_weights
from recon.garment.templates import GarmentSpec, RestBody, make_outfit
from recon.poses.mocap import MocapPoses


def _sequence(body, t=6, seed=0, yaw=0.0):
    """A random smooth motion (B=1, T) and its FK: local, global rotations, joint locations."""
    g = torch.Generator().manual_seed(seed)
    base, vel = 0.3 * torch.randn(24, 3, generator=g), 0.05 * torch.randn(24, 3, generator=g)
    rv = torch.stack([base + i * vel + 0.02 * i * i * vel for i in range(t)])
    rot = roma.rotvec_to_rotmat(rv)
    turn = roma.rotvec_to_rotmat(torch.tensor([0.0, yaw, 0.0]))
    rot[:, 0] = turn @ rot[:, 0]
    transl = torch.stack([torch.tensor([0.1 * i * i, 0.9, 0.05 * i]) for i in range(t)]) @ turn.T
    with torch.no_grad():
        rest_j = body().joints.expand(t, -1, -1)
    glob, joints, _ = forward_kinematics(rot, rest_j, skeleton.JOINT_PARENTS)
    joints = joints - joints[:, :1] + transl[:, None]
    return rot[None], glob[None], joints[None]


def test_descriptor_shapes_and_gravity(body):
    rot, glob, joints = _sequence(body)
    s, d = ncs.descriptors(rot, glob, joints)
    k = len(ncs.KEPT)
    assert k == 20 and s.shape == (1, 6, k, 9) and d.shape == (1, 6, k, 12)
    assert torch.allclose(s[..., 6:].norm(dim=-1), torch.ones(1, 6, k), atol=1e-5)  # unit gravity
    rest = torch.eye(3).expand(1, 1, 24, 3, 3)
    s0 = ncs.static_descriptors(rest, rest)
    assert torch.allclose(s0[0, 0, 0], torch.tensor([1.0, 0, 0, 0, 1, 0, 0, -1, 0]))  # identity; gravity -Y


def test_descriptors_do_not_see_the_heading(body):
    """Eq. 6.5's point: turning the whole motion about gravity changes no descriptor."""
    a = ncs.descriptors(*_sequence(body))
    b = ncs.descriptors(*_sequence(body, yaw=1.1))
    for x, y in zip(a, b):
        assert torch.allclose(x, y, rtol=1e-4, atol=2e-5 * float(x.abs().max()))


def test_no_motion_no_dynamic_code(body):
    """A still pose: zero dynamic descriptors, so the bias-free branch gives a zero code and the
    output is the static model's at every frame."""
    rot, glob, joints = _sequence(body, t=1)
    rep = lambda x: x.expand(-1, 5, *x.shape[2:])  # noqa: E731
    s, d = ncs.descriptors(rep(rot), rep(glob), rep(joints))
    assert d.abs().max() == 0
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    w = initial_weights(RestBody(body), o)
    torch.manual_seed(0)
    model = ncs.NCS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces), torch.from_numpy(w))
    with torch.no_grad():
        model.D.normal_(0, 1e-3)
        zs, zd, _ = model.codes(s, d)
        dt, _ = model.deformation(s, d)
    assert zd.abs().max() == 0
    assert torch.allclose(dt[:, 0], dt[:, -1])
    s2, d2 = ncs.descriptors(*_sequence(body))
    with torch.no_grad():
        moving, _ = model.deformation(s2, d2)
        still, _ = model.deformation(s2, d2, motion=0.0)  # motion control 0: the static model
        zs2, zd2, _ = model.codes(s2, d2)
    assert zd2.abs().max() > 0 and not torch.allclose(moving, still)
    assert torch.allclose(still, (zs2 @ model.D).view_as(still), atol=1e-6)


def test_dynamic_modes_are_reached_by_the_dynamic_code_only(body, windows):
    """NCSConfig.dynamic_modes adds rows to D after PBNS's: the static code is zero there, so at
    motion control 0 NCS decodes with PBNS's rows alone; the dynamic code reaches all rows."""
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    torch.manual_seed(0)
    pbns = PBNS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                torch.from_numpy(initial_weights(RestBody(body), o)))
    with torch.no_grad():
        pbns.D.normal_(0, 1e-3)
    model = ncs.NCS.from_pbns(pbns, ncs.NCSConfig(dynamic_modes=8))
    assert model.D.shape == (136, pbns.D.shape[1]) and torch.equal(model.D[:128], pbns.D)
    with torch.no_grad():
        model.D[128:].normal_(0, 1e-3)
        s, d = ncs.descriptors(*_sequence(body))
        zs, zd, _ = model.codes(s, d)
        still, _ = model.deformation(s, d, motion=0.0)
    assert zs.shape[-1] == zd.shape[-1] == 136 and zs[..., 128:].abs().max() == 0 and zd[..., 128:].abs().max() > 0
    assert torch.allclose(still, (zs[..., :128] @ pbns.D).view_as(still), atol=1e-6)
    assert np.isfinite(distil_static(model, pbns, windows, steps=2, seed=0))  # the static code has 128 entries


def test_gru_state_fades_when_motion_stops(body):
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    model = ncs.NCS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                    torch.from_numpy(initial_weights(RestBody(body), o)))
    s, d = ncs.descriptors(*_sequence(body, t=4))
    with torch.no_grad():
        _, _, h = model.codes(s, d)
        still = torch.zeros(1, 60, len(ncs.KEPT), 12)
        _, zd, _ = model.codes(s[:, -1:].expand(-1, 60, -1, -1), still, h)
    assert zd[0, -1].norm() < 0.05 * zd[0, 0].norm()


def test_the_dynamic_branch_keeps_a_gradient_when_every_hidden_unit_is_negative(body):
    """No biases: a hidden unit fed by the per-joint layers (outputs >= 0 under a ReLU) whose weights
    turn negative is off for every input, and with ReLUs the whole branch died in training (every
    hidden unit off, the dynamic code zero for good). The leaky activations keep a gradient."""
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    model = ncs.NCS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                    torch.from_numpy(initial_weights(RestBody(body), o)))
    with torch.no_grad():
        model.dynamic[0].weight.copy_(-model.dynamic[0].weight.abs())
    s, d = ncs.descriptors(*_sequence(body, t=4))
    pj = model.per_joint(d).abs().detach()  # what ReLU per-joint layers would feed: >= 0
    assert (model.dynamic[0](pj.reshape(1, 4, -1))[:, 1:] < 0).all()  # every hidden unit below zero (frame 0: at rest)
    model.dynamic(pj.reshape(1, 4, -1)).square().sum().backward()
    assert model.dynamic[0].weight.grad.abs().max() > 0
    acts = [m for m in (*model.per_joint, *model.dynamic) if not isinstance(m, torch.nn.Linear)]
    assert acts and all(isinstance(m, torch.nn.LeakyReLU) for m in acts)


def test_inertia_is_zero_at_constant_velocity_and_never_looks_back():
    m = torch.tensor([0.5, 1.0])
    loss = ncs.InertiaLoss(m, fps=30.0, cfg=ncs.InertiaConfig(weight=1.0))
    x0, x1 = torch.zeros(1, 2, 3), torch.full((1, 2, 3), 0.01)
    assert loss(2 * x1 - x0, x1, x0).abs().max() < 1e-12
    prev, prev2 = x1.clone().requires_grad_(), x0.clone().requires_grad_()
    x = torch.full((1, 2, 3), 0.05, requires_grad=True)
    v = loss(x, prev, prev2)
    v.sum().backward()
    assert prev.grad is None and prev2.grad is None and x.grad.abs().sum() > 0
    expected = 0.5 * 900 * (m / m.mean() * (3 * 0.03 ** 2)).mean()  # masses scaled to a mean of 1
    assert v.item() == pytest.approx(expected.item(), rel=1e-5)


def test_inertia_gradcheck_float64():
    m = torch.rand(5, dtype=torch.float64) + 0.1
    loss = ncs.InertiaLoss(m, fps=30.0)
    prev, prev2 = torch.randn(2, 5, 3, dtype=torch.float64), torch.randn(2, 5, 3, dtype=torch.float64)
    x = torch.randn(2, 5, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda y: loss(y, prev, prev2), (x,))


def test_vertex_masses_sum_to_area_times_density():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    m = ncs.vertex_masses(v, f, density=0.2)
    assert m.sum() == pytest.approx(0.2) and m[0] == pytest.approx(m[2]) and m[0] > m[1]


def test_smoothing_keeps_still_motion_and_removes_jitter():
    x = torch.zeros(1, 40, 2, 3)
    assert torch.allclose(ncs.smooth_time(x + 1.5, 2.0), x + 1.5)  # constants stay (edges repeated)
    jitter = x.clone()
    jitter[:, ::2] = 0.01
    assert ncs.smooth_time(jitter, 2.0)[:, 5:-5].std() < 0.05 * jitter.std()


@pytest.fixture(scope="module")
def windows(body):
    return MotionWindows(body, "val", body.mean_shape[None], frames=10, n=12, seed=0, smooth=1.5)


def test_windows_stay_inside_their_clip(windows):
    clip = torch.from_numpy(MocapPoses.load("val").clip)
    f = windows.ends[:, None] + windows.offsets
    assert f.shape == (12, 10) and (clip[f] == clip[f[:, :1]]).all()
    s, d = windows.window(torch.arange(3))
    assert s.shape == (3, 10, len(ncs.KEPT), 9) and d.shape == (3, 10, len(ncs.KEPT), 12)
    # each window is moved so that its last frame's root translation is above the origin
    assert windows.transforms[:, 2, 0, [0, 2], 3].abs().max() < 0.25
    assert windows.transl[windows.ends][:, [0, 2]].abs().max() > 0.5


def test_training_step_sends_no_gradient_back_in_time_or_into_encoders_for_augmented(body, windows):
    """With every window augmented, only D and the blend weights learn (6.4.6); the inertia
    term's gradient reaches the encoders only through x_t."""
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    model = ncs.NCS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                    torch.from_numpy(initial_weights(RestBody(body), o)))
    with torch.no_grad():
        model.D.normal_(0, 1e-3)  # a fresh D is zero: no gradient would reach any code
    cfg = NCSTrainConfig()
    crit = L.Criterion(o, model.rest, cfg)
    inertia = ncs.InertiaLoss(torch.from_numpy(ncs.vertex_masses(o.vertices, o.faces)), cfg=cfg.inertia)
    step = Step(model, crit, inertia, windows, augmentation=1.0)
    loss, terms = step(torch.arange(4))
    loss.backward()
    assert model.D.grad.abs().sum() > 0
    assert all(p.grad is None or p.grad.abs().sum() == 0 for p in model.static.parameters())
    assert all(p.grad is None or p.grad.abs().sum() == 0 for p in model.gru.parameters())
    model.zero_grad()
    loss, terms = Step(model, crit, inertia, windows)(torch.arange(4))
    loss.backward()
    assert terms["inertia"].shape == (4,) and model.dynamic[0].weight.grad.abs().sum() > 0


def test_frozen_static_part_keeps_pbns_and_trains_the_dynamic_branch(body, windows):
    """freeze_static: a training step changes the dynamic branch only, so NCS at motion control 0
    still decodes the distilled PBNS codes."""
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    model = ncs.NCS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                    torch.from_numpy(initial_weights(RestBody(body), o)))
    with torch.no_grad():
        model.D.normal_(0, 1e-3)
    cfg = NCSTrainConfig(freeze_static=True)
    before = {n: p.detach().clone() for n, p in model.named_parameters()}
    opt = torch.optim.Adam(param_groups(model, cfg))
    crit = L.Criterion(o, model.rest, cfg)
    inertia = ncs.InertiaLoss(torch.from_numpy(ncs.vertex_masses(o.vertices, o.faces)), cfg=cfg.inertia)
    loss, _ = Step(model, crit, inertia, windows)(torch.arange(4))
    loss.backward()
    opt.step()
    changed = {n for n, p in model.named_parameters() if not torch.equal(p, before[n])}
    assert changed and all(n.split(".")[0] in ("per_joint", "dynamic", "gru") for n in changed)
    assert len(param_groups(model, NCSTrainConfig())) == 3
    # with dynamic-only rows in D, those rows train and PBNS's stay
    modes = ncs.NCS.from_pbns(model, ncs.NCSConfig(dynamic_modes=4))
    opt = torch.optim.Adam(param_groups(modes, cfg))
    d0 = modes.D.detach().clone()
    Step(modes, crit, inertia, windows)(torch.arange(4))[0].backward()
    opt.step()
    assert torch.equal(modes.D[:128], d0[:128]) and not torch.equal(modes.D[128:], d0[128:])
    # train_dynamic_rows=False: D stays whole, the dynamic branch alone trains
    fixed = replace(cfg, train_dynamic_rows=False)
    modes = ncs.NCS.from_pbns(model, ncs.NCSConfig(dynamic_modes=4))
    opt = torch.optim.Adam(param_groups(modes, fixed))
    d0 = modes.D.detach().clone()
    Step(modes, crit, inertia, windows)(torch.arange(4))[0].backward()
    opt.step()
    assert torch.equal(modes.D, d0) and modes.per_joint[0].weight.grad.abs().sum() > 0


def test_animated_glb_holds_the_dynamic_model(body, tmp_path):
    """A dynamic Dresser: the .glb's morph targets are NCS's D and its weights NCS's codes, so the
    file poses the outfit as ``Dresser.animate`` does (which differs from PBNS frame by frame)."""
    torch.manual_seed(0)
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    pbns = PBNS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                torch.from_numpy(initial_weights(RestBody(body), o)))
    with torch.no_grad():
        pbns.D.normal_(0, 1e-3)
    path = tmp_path / "m.pt"
    pbns.save(path, {"meta_json": json.dumps({"garments": ["skirt"]}), "layer": torch.zeros(len(o.vertices)),
                     "garment_id": torch.zeros(len(o.vertices), dtype=torch.long), "shape": body.mean_shape})
    dresser = Dresser(path=path, resolve_collisions=False)
    assert not dresser.dynamic
    dresser.ncs = ncs.NCS.from_pbns(dresser.model)
    rot, glob, joints = _sequence(body, t=5)
    transl = joints[0, :, 0] - joints[0, :1, 0] + torch.tensor([0.0, 0.9, 0.0])
    glb = write_glb(tmp_path / "a.glb", body, body.mean_shape, rot[0], transl, 30.0, dresser)
    assert_valid(glb)
    moving = dresser.animate(body, rot[0], body.mean_shape, transl).vertices
    dresser_static = Dresser(path=path, resolve_collisions=False)
    still = dresser_static.animate(body, rot[0], body.mean_shape, transl).vertices
    posed = pose_meshes(glb, 4)["outfit"]
    assert np.abs(posed - moving[4]).max() < 1e-4
    assert np.abs(moving[4] - still[4]).max() > 1e-3  # NCS is not PBNS here


def test_a_network_trained_at_15_fps_dresses_a_30_fps_motion(body, tmp_path):
    """The Dresser resamples the motion to the network's rate and interpolates its codes back: at
    the shared frames (every second one) the codes are those of the network run at 15 fps."""
    torch.manual_seed(0)
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    pbns = PBNS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                torch.from_numpy(initial_weights(RestBody(body), o)))
    path = tmp_path / "m.pt"
    pbns.save(path, {"meta_json": json.dumps({"garments": ["skirt"]}), "layer": torch.zeros(len(o.vertices)),
                     "garment_id": torch.zeros(len(o.vertices), dtype=torch.long), "shape": body.mean_shape})
    dresser = Dresser(path=path, resolve_collisions=False)
    dresser.ncs = ncs.NCS(pbns.rest, pbns.faces, pbns.weights.detach(), ncs.NCSConfig(fps=15.0))
    rot, _, joints = _sequence(body, t=9)
    transl = joints[0, :, 0] - joints[0, :1, 0]
    _, z30 = dresser.sequence_codes(body, rot[0], body.mean_shape, transl, fps=30.0)
    _, z15 = dresser.sequence_codes(body, rot[0, ::2], body.mean_shape, transl[::2], fps=15.0)
    assert z30.shape == (9, 128) and z15.shape == (5, 128)
    assert torch.allclose(z30[::2], z15, atol=1e-5)
    assert torch.allclose(z30[1], 0.5 * (z15[0] + z15[1]), atol=1e-5)


def test_hem_is_the_lowest_boundary_ring_and_held_clips_stop_dead():
    tube = trimesh.creation.cylinder(radius=0.3, height=0.5, sections=24)
    tube = trimesh.Trimesh(tube.vertices, tube.faces[np.abs(tube.face_normals[:, 2]) < 0.5])  # open ends
    v = tube.vertices[:, [0, 2, 1]]  # the axis along +Y
    hem = hem_vertices(v, tube.faces)
    assert len(hem) == 24 and np.allclose(v[hem, 1], v[:, 1].min())
    rot, tr = _clip(MocapPoses.load("test"), "12_01", 10, 5, hold=3)
    assert rot.shape == (8, 24, 3, 3) and torch.equal(rot[4], rot[7]) and torch.equal(tr[4], tr[7])
    assert tr[0, [0, 2]].abs().max() == 0  # the first frame's pelvis above the origin


def test_the_reference_simulates_pinned_garments_or_holds_an_unpinned_outfit_by_its_top_band():
    class Outfit:  # two garments stacked in y; what ncs.hanging_part reads of an outfit
        vertices = np.stack([np.zeros(8), np.linspace(0.0, 0.7, 8), np.zeros(8)], 1)
        garment_id = np.array([0, 0, 0, 0, 1, 1, 1, 1])
        pinned = np.zeros(8, bool)

    skirt = Outfit()
    skirt.pinned = np.array([0, 0, 0, 1, 0, 0, 0, 0], bool)  # garment 0 hangs from a pin
    sub, held = ncs.hanging_part(skirt)
    assert sub.tolist() == [True] * 4 + [False] * 4 and held.tolist() == skirt.pinned.tolist()
    sub, held = ncs.hanging_part(Outfit())  # nothing pinned: all of it, held at each garment's top
    top = np.array([3, 7])
    assert sub.all() and np.nonzero(held)[0].tolist() == top.tolist()
    assert np.diff(Outfit.vertices[:, 1])[0] > ncs.SHOULDER_BAND  # the next vertex down is free


def test_swing_basis_rises_from_the_held_waist_to_the_hem(body):
    """swing_basis: the hanging part's lowest membrane modes, zero where it is held, one horizontal
    axis per row, mass-orthogonal; the first has one sign and is largest at the hem (a pendulum's
    swing)."""
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    n, masses = len(o.vertices), ncs.vertex_masses(o.vertices, o.faces)
    hanging, held = ncs.hanging_part(o)
    rows = ncs.swing_basis(o.vertices, o.faces, masses, hanging, held, 4)
    assert ncs.SWING_AXES == (0, 2) and rows.shape == (8, n * 3) and rows.dtype == np.float32
    f = rows.reshape(4, 2, n, 3)
    assert np.abs(f[:, :, held]).max() == 0 and held.any()
    assert np.abs(f[..., 1]).max() == 0  # nothing vertical
    for j, axis in enumerate(ncs.SWING_AXES):  # row (k, axis) moves along that axis only
        assert np.abs(f[:, j, :, 2 - axis]).max() == 0
        assert np.allclose(np.abs(f[:, j, :, axis]).max(1), ncs.SWING_AMPLITUDE)
    phi = f[:, 0, :, 0].astype(np.float64)
    gram = (phi * masses) @ phi.T
    assert np.abs(gram - np.diag(np.diag(gram))).max() < 1e-3 * np.diag(gram).min()
    first = phi[0] * np.sign(phi[0].sum())
    assert first.min() > -1e-6
    hem = hem_vertices(o.vertices, o.faces)
    assert first[hem].mean() > 0.9 * first.max() > 0.2 * first[hem].mean()


def test_swing_modes_are_appended_to_D_from_the_outfit(body):
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    pbns = PBNS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                torch.from_numpy(initial_weights(RestBody(body), o)))
    cfg = ncs.NCSConfig(dynamic_modes=2, swing_modes=3)
    with pytest.raises(ValueError, match="outfit"):
        ncs.NCS.from_pbns(pbns, cfg)
    model = ncs.NCS.from_pbns(pbns, cfg, o)
    basis = ncs.swing_basis(o.vertices, o.faces, ncs.vertex_masses(o.vertices, o.faces), *ncs.hanging_part(o), 3)
    assert model.D.shape == (128 + 2 + 6, pbns.D.shape[1]) and model.gru.hidden_size == 136
    assert torch.equal(model.D[-6:], torch.from_numpy(basis)) and model.D[128:130].abs().max() == 0
    s, d = ncs.descriptors(*_sequence(body))
    zs, zd, _ = model.codes(s, d)
    assert zs.shape[-1] == 136 and zs[..., 128:].abs().max() == 0
    only = ncs.NCS.from_pbns(pbns, ncs.NCSConfig(swing_modes=3, dynamic_in_static_rows=False), o)
    _, zd, _ = only.codes(s, d)
    assert zd[..., :128].abs().max() == 0 and zd[..., 128:].abs().max() > 0


def test_motion_codes_run_the_network_at_its_own_rate(body):
    """A 15-fps NCS dressing a 30-fps motion steps at 15 fps: its codes at the even frames are those
    of the network run on every second frame (the motion resampled), the odd ones interpolated."""
    o = make_outfit(body, [GarmentSpec("skirt", "skirt")])
    torch.manual_seed(0)
    model = ncs.NCS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                    torch.from_numpy(initial_weights(RestBody(body), o)), ncs.NCSConfig(fps=15.0))
    rot = _sequence(body, t=9)[0][0]
    shape = body.mean_shape
    z30 = sum(model.motion_codes(body, rot, shape, fps=30.0))
    z15 = sum(model.motion_codes(body, rot[::2], shape, fps=15.0))
    assert z30.shape == (9, 128) and torch.allclose(z30[::2], z15, atol=1e-5)
    assert torch.allclose(z30[1], 0.5 * (z15[0] + z15[1]), atol=1e-5)


def test_training_on_the_hanging_part_alone_matches_the_whole_outfit(body, windows):
    """With the static part frozen and the dynamic code on the swing rows only, nothing outside
    the hanging skirt can move: the part shares the encoders, its loss gradient on them points
    where the whole outfit's does (the top's energies are constants; the cloth-cloth collisions
    between the two are off here), and ``set_part`` writes the skirt's columns of D alone."""
    o = make_outfit(body, [GarmentSpec("top", "top", sleeve=0.0), GarmentSpec("skirt", "skirt")])
    pbns = PBNS(torch.from_numpy(o.vertices), torch.from_numpy(o.faces),
                torch.from_numpy(initial_weights(RestBody(body), o)))
    mcfg = ncs.NCSConfig(swing_modes=2, dynamic_in_static_rows=False)
    cfg = NCSTrainConfig(freeze_static=True, model=mcfg, collision=replace(NCSTrainConfig().collision, weight=0.0))
    model = ncs.NCS.from_pbns(pbns, mcfg, o)
    part = hanging_part_to_train(model, o, cfg)
    skirt = o.garment_id == [i for i, g in enumerate(o.garments) if g.pinned.any()][0]
    assert np.array_equal(part, np.nonzero(skirt)[0])
    assert hanging_part_to_train(model, o, replace(cfg, hanging_only=False)) is None
    assert hanging_part_to_train(model, o, replace(cfg, freeze_static=False)) is None
    cloth = part_outfit(o, part)
    sub = model.part(part, cloth.faces)
    assert sub.gru is model.gru and torch.equal(sub.rest, model.rest[part])

    def grads(m, outfit):
        crit = L.Criterion(outfit, m.rest, cfg)
        inertia = ncs.InertiaLoss(torch.from_numpy(ncs.vertex_masses(outfit.vertices, outfit.faces)), cfg=cfg.inertia)
        model.zero_grad()
        Step(m, crit, inertia, windows)(torch.arange(4))[0].backward()
        return model.dynamic[0].weight.grad.clone()

    param_groups(model, replace(cfg, train_dynamic_rows=False))
    g_part, g_all = grads(sub, cloth), grads(model, o)
    # the energies are per mean vertex: the same direction, scaled by the vertex counts (Adam's
    # steps do not see the scale)
    assert torch.nn.functional.cosine_similarity(g_part.flatten(), g_all.flatten(), 0) > 0.9999
    assert abs(g_part.norm() / g_all.norm() / (len(o.vertices) / len(part)) - 1) < 0.05
    d0 = model.D.detach().clone()
    with torch.no_grad():
        sub.D[-1] += 1.0
    model.set_part(part, sub)
    moved = (model.D - d0).view(len(d0), -1, 3).abs().sum((0, 2)) > 0
    assert torch.equal(moved, torch.from_numpy(skirt))


@pytest.mark.slow
def test_training_on_the_hanging_part_writes_a_whole_outfit_model(body, tmp_path):
    """``train`` on the shipped tshirt-skirt with the static part frozen and the dynamic code on
    fixed swing modes trains the skirt alone: the saved model covers the whole outfit, decodes
    PBNS's D on every row it had, and its dynamic code moves the skirt and nothing else."""
    cfg = NCSTrainConfig(samples=32, val_samples=8, epochs=1, distil_steps=10, freeze_static=True,
                         train_dynamic_rows=False, model=ncs.NCSConfig(swing_modes=2, dynamic_in_static_rows=False))
    meta = train(body, cfg, out=tmp_path / "n.pt", log=lambda *_: None, progress=False)
    model, _ = ncs.NCS.load(tmp_path / "n.pt")
    pbns, _ = PBNS.load(store.pbns_path("tshirt-skirt"))
    assert meta["trained_vertices"] < meta["vertices"] == len(model.rest)
    assert torch.equal(model.D[:len(pbns.D)], pbns.D)
    assert meta["curve"][-1]["val_dynamic_mm"] > 0
    s, d = ncs.descriptors(*_sequence(body))
    zs, zd, _ = model.codes(s, d)
    moved = model.decode(zd).abs().sum((0, 1, 3)) > 0
    hanging, _ = ncs.hanging_part(trained_outfit(body, store.pbns_path("tshirt-skirt"))[0])
    assert moved.any() and not moved[torch.from_numpy(~hanging)].any()
