"""Reference cloth simulation with newton 1.8.0 SolverVBD, to compare PBNS (thesis Table 5.1) and
NCS against physics. Optional extra: ``pip install "recon[sim]"`` (newton==1.8.0, warp-lang).
``drape`` settles a garment on a posed body; ``simulate`` runs it through a motion.

Protocol (quasi-static drape on a static body, CPU): the body in the target pose is a static
mesh collider. The cloth keeps the outfit's rest shape as its rest state (edge lengths, triangle
shapes) and starts from the skinning-only garment (rest outfit + linear blend skinning to the
pose: no PBNS deformation, so the reference owes nothing to the network). Pinned vertices stay
at their skinned positions. Gravity pulls, body contact pushes out.

Quasi-static: velocities are reset to zero after every substep, so each substep is one implicit
relaxation step of gravity + elasticity + contact. Dynamic VBD (velocities kept) does not hold a
1-cm-resolution garment on the body at 5-10 iterations: the cloth keeps falling at nearly
free-fall and the collar stretches over the shoulders (likely because Gauss-Seidel carries the
shoulders' support only a few rings of vertices per iteration). The
drape stops when the particles moved less than ``settle_mm`` in the last frame (99th percentile
over particles: a few light particles at sliver triangles keep jittering by millimetres) or
after ``frames`` frames.

Dynamic (``simulate``, for NCS): the drape of the first frame, then velocities are kept while the
body mesh and the pinned vertices move linearly from frame to frame, 20 substeps a frame. Given
where the body carries the cloth (the skinned outfit), the cloth starts at that velocity (a clip
cut from a run does not start with the cloth at rest around a running body) and ``keep_velocity``
damps its velocity relative to it, a frame at a time (the fabric's damping of its swing; the air
moves with the body). Damped relative to the world instead, the same 5 % a frame is a wind of still
air, 5 m/s^2 on a runner's skirt at 3.5 m/s, which blows it back by tens of cm. A skirt hanging
from its pinned waist holds this way (eval/results/garment-ncs.md), which the free fall above
does not contradict: the pins carry it.

Body sign: a posed body self-intersects (armpits, groin), which breaks ray-parity inside tests;
the collider uses the pseudo-normal sign instead.

"""
from __future__ import annotations

import importlib.util
import time
from dataclasses import dataclass

import numpy as np
import warp as wp


@dataclass
class DrapeConfig:
    fps: float = 30.0
    substeps: int = 10
    iterations: int = 10
    frames: int = 60
    settle_mm: float = 0.5  # 99th percentile of particle displacement in one frame
    density: float = 0.15  # kg/m^2
    tri_ke: float = 1.0e4
    tri_ka: float = 1.0e4
    tri_kd: float = 1.0e-4
    edge_ke: float = 1.0e-2
    particle_radius: float = 0.003
    contact_ke: float = 1.0e4
    contact_kd: float = 1.0e-2
    contact_mu: float = 0.3
    contact_gap: float = 0.01  # m: contact search distance beyond the particle radius


def available() -> bool:
    """Whether the optional newton package (extra ``sim``) is installed."""
    return importlib.util.find_spec("newton") is not None


def _system(body_vertices: np.ndarray, body_faces: np.ndarray, rest: np.ndarray, start: np.ndarray,
            faces: np.ndarray, pinned: np.ndarray, cfg: DrapeConfig):
    """The newton model of a cloth (rest shape ``rest``, starting at ``start``, ``pinned``
    vertices kinematic) and a body mesh collider; returns (model, collider mesh, collision
    pipeline, contacts, solver)."""
    import newton  # noqa: PLC0415 - optional extra (sim), imported only when a simulation runs

    wp.config.quiet = True
    builder = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=(0.0, -9.81, 0.0))
    builder.default_shape_cfg.ke = cfg.contact_ke
    builder.default_shape_cfg.kd = cfg.contact_kd
    builder.default_shape_cfg.mu = cfg.contact_mu
    collider = newton.Mesh(body_vertices.astype(np.float32), body_faces.astype(np.int32).reshape(-1))
    collider._is_watertight = False  # pseudo-normal sign: parity fails on a self-intersecting posed body
    builder.add_shape_mesh(body=-1, mesh=collider)
    cloth = dict(pos=wp.vec3(0.0, 0.0, 0.0), rot=wp.quat_identity(), scale=1.0, vel=wp.vec3(0.0, 0.0, 0.0),
                 indices=faces.astype(np.int32).reshape(-1).tolist(), density=cfg.density, tri_ke=cfg.tri_ke,
                 tri_ka=cfg.tri_ka, tri_kd=cfg.tri_kd, edge_ke=cfg.edge_ke, particle_radius=cfg.particle_radius)
    # particles start at `start`; triangle/edge rest quantities and masses come from the rest shape
    ref = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=(0.0, -9.81, 0.0))
    ref.add_cloth_mesh(vertices=[wp.vec3(*p) for p in rest.astype(np.float32)], **cloth)
    p0, t0_, e0 = builder.particle_count, len(builder.tri_poses), len(builder.edge_rest_angle)
    builder.add_cloth_mesh(vertices=[wp.vec3(*p) for p in start.astype(np.float32)], **cloth)
    assert len(builder.tri_poses) - t0_ == len(ref.tri_poses)
    assert len(builder.edge_rest_angle) - e0 == len(ref.edge_rest_angle)
    builder.tri_poses[t0_:] = ref.tri_poses
    builder.tri_areas[t0_:] = ref.tri_areas
    builder.edge_rest_angle[e0:] = ref.edge_rest_angle
    builder.edge_rest_length[e0:] = ref.edge_rest_length
    builder.particle_mass[p0:] = ref.particle_mass
    builder.color(include_bending=True)
    for i in np.nonzero(pinned)[0]:  # kinematic: no mass, inactive
        builder.particle_mass[i] = 0.0
        builder.particle_flags[i] = builder.particle_flags[i] & ~int(newton.ParticleFlags.ACTIVE)
    model = builder.finalize()
    model.soft_contact_ke, model.soft_contact_kd, model.soft_contact_mu = cfg.contact_ke, cfg.contact_kd, cfg.contact_mu
    pipeline = newton.CollisionPipeline(model, soft_contact_gap=cfg.contact_gap)
    solver = newton.solvers.SolverVBD(model, iterations=cfg.iterations)
    return model, collider, pipeline, pipeline.contacts(), solver


def drape(body_vertices: np.ndarray, body_faces: np.ndarray, rest: np.ndarray, start: np.ndarray, faces: np.ndarray,
          pinned: np.ndarray, cfg: DrapeConfig | None = None, log=None) -> dict:
    """Settle a garment (rest shape ``rest``, initial positions ``start``) on a static body.
    Returns {"vertices": (N, 3), "frames", "settled", "final_speed", "seconds"}."""
    cfg = cfg or DrapeConfig()
    t0 = time.time()
    model, _, pipeline, contacts, solver = _system(body_vertices, body_faces, rest, start, faces, pinned, cfg)
    s0, s1, control = model.state(), model.state(), model.control()
    s0, info = _settle(s0, s1, control, pipeline, contacts, solver, cfg, log)
    return {"vertices": s0.particle_q.numpy().astype(np.float64), **info, "seconds": time.time() - t0}


def _settle(s0, s1, control, pipeline, contacts, solver, cfg: DrapeConfig, log=None):
    """Quasi-static relaxation (velocities zeroed after every substep) until the 99th percentile
    of a frame's particle moves is below ``settle_mm`` or ``frames`` frames; returns the state
    and {"frames", "settled", "last_move_mm", "move_history_mm"}."""
    dt = 1.0 / cfg.fps / cfg.substeps
    frames, settled, moved, history = 0, False, float("inf"), []
    for f in range(cfg.frames):
        before = s0.particle_q.numpy().copy()
        for _ in range(cfg.substeps):
            pipeline.collide(s0, contacts)
            s0.clear_forces()
            solver.step(s0, s1, control, contacts, dt)
            s0, s1 = s1, s0
            s0.particle_qd.zero_()
        frames = f + 1
        step = np.linalg.norm(s0.particle_q.numpy() - before, axis=1) * 1000
        moved = float(np.percentile(step, 99))
        history.append(moved)
        if log:
            log(f"frame {frames}: move p99 {moved:.2f} mm, max {step.max():.2f} mm")
        if moved < cfg.settle_mm:
            settled = True
            break
    return s0, {"frames": frames, "settled": settled, "last_move_mm": moved, "move_history_mm": history}


@dataclass
class DynamicConfig(DrapeConfig):
    substeps: int = 20
    # velocity kept from substep to substep, times this per frame (air drag and the fabric's own
    # damping: 1 keeps all of it)
    keep_velocity: float = 0.95


def simulate(body_frames: np.ndarray, body_faces: np.ndarray, rest: np.ndarray, start: np.ndarray, faces: np.ndarray,
             pinned: np.ndarray, pinned_frames: np.ndarray, cfg: DynamicConfig | None = None,
             carried: np.ndarray | None = None, log=None) -> dict:
    """Dynamic cloth on a moving body: ``body_frames`` (T, V, 3) at ``cfg.fps``, the cloth
    settled quasi-statically on frame 0 (from ``start``), then stepped with its velocities through
    the motion; the body collider and the pinned vertices (``pinned_frames`` (T, P, 3)) move
    linearly between frames. ``carried`` (T, N, 3): where the body carries the cloth (the skinned
    outfit); the cloth starts at its velocity and ``cfg.keep_velocity`` damps the velocity relative
    to it (None: the cloth starts at rest and is damped relative to the world, a drag of still air).
    Returns {"vertices": (T, N, 3), "drape": settling record, "seconds"}."""
    cfg = cfg or DynamicConfig()
    t0 = time.time()
    model, collider, pipeline, contacts, solver = _system(body_frames[0], body_faces, rest, start, faces, pinned, cfg)
    s0, s1, control = model.state(), model.state(), model.control()
    s0, info = _settle(s0, s1, control, pipeline, contacts, solver, cfg)
    if carried is not None:
        s0.particle_qd.assign(((carried[1] - carried[0]) * cfg.fps).astype(np.float32))
    s1.particle_q.assign(s0.particle_q)
    pins = np.nonzero(pinned)[0]
    dt = 1.0 / cfg.fps / cfg.substeps
    decay = cfg.keep_velocity ** (1.0 / cfg.substeps)
    out = [s0.particle_q.numpy().copy()]
    mesh = collider.mesh
    for t in range(1, len(body_frames)):
        body_v = (body_frames[t] - body_frames[t - 1]) * cfg.fps
        pin_v = (pinned_frames[t] - pinned_frames[t - 1]) * cfg.fps
        carry_v = 0.0 if carried is None else (carried[t] - carried[t - 1]) * cfg.fps
        mesh.velocities.assign(body_v.astype(np.float32))
        for k in range(cfg.substeps):
            a = (k + 1) / cfg.substeps
            mesh.points.assign((body_frames[t - 1] + a * (body_frames[t] - body_frames[t - 1])).astype(np.float32))
            mesh.refit()
            if len(pins):
                q, qd = s0.particle_q.numpy(), s0.particle_qd.numpy()
                q[pins] = pinned_frames[t - 1] + a * (pinned_frames[t] - pinned_frames[t - 1])
                qd[pins] = pin_v
                s0.particle_q.assign(q)
                s0.particle_qd.assign(qd)
            pipeline.collide(s0, contacts)
            s0.clear_forces()
            solver.step(s0, s1, control, contacts, dt)
            s0, s1 = s1, s0
            if decay < 1.0:
                s0.particle_qd.assign((carry_v + (s0.particle_qd.numpy() - carry_v) * decay).astype(np.float32))
        out.append(s0.particle_q.numpy().copy())
        if log:
            log(f"frame {t}: {time.time() - t0:.0f} s")
    return {"vertices": np.stack(out).astype(np.float64), "drape": info, "seconds": time.time() - t0}
