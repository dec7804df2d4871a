"""Reference cloth simulation with newton 1.8.0 SolverVBD, to compare PBNS against physics (thesis
Table 5.1). Optional extra: ``pip install "recon[sim]"`` (newton==1.8.0, warp-lang).

Protocol (quasi-static drape on a static body, CPU): the body in the target pose is a static
mesh collider. The cloth keeps the outfit's rest shape as its rest state (edge lengths, triangle
shapes) and starts from the skinning-only garment (rest outfit + linear blend skinning to the
pose: no PBNS deformation, so the reference owes nothing to the network). Pinned vertices stay
at their skinned positions. Gravity pulls, body contact pushes out.

Quasi-static: velocities are reset to zero after every substep, so each substep is one implicit
relaxation step of gravity + elasticity + contact. Dynamic VBD (velocities kept) does not hold a
1-cm-resolution garment on the body at 5-10 iterations: the cloth keeps falling at nearly
free-fall and the collar stretches up to 3.5x over the shoulders (measured; likely because
Gauss-Seidel carries the shoulders' support only a few rings of vertices per iteration). The
drape stops when the particles moved less than ``settle_mm`` in the last frame (99th percentile
over particles: a few light particles at sliver triangles keep jittering by millimetres) or
after ``frames`` frames.

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


def drape(body_vertices: np.ndarray, body_faces: np.ndarray, rest: np.ndarray, start: np.ndarray, faces: np.ndarray,
          pinned: np.ndarray, cfg: DrapeConfig | None = None, log=None) -> dict:
    """Settle a garment (rest shape ``rest``, initial positions ``start``) on a static body.
    Returns {"vertices": (N, 3), "frames", "settled", "final_speed", "seconds"}."""
    import newton  # noqa: PLC0415 - optional extra (sim), imported only when a drape runs

    cfg = cfg or DrapeConfig()

    wp.config.quiet = True
    t0 = time.time()
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
    contacts = pipeline.contacts()
    solver = newton.solvers.SolverVBD(model, iterations=cfg.iterations)
    s0, s1, control = model.state(), model.state(), model.control()
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
    return {"vertices": s0.particle_q.numpy().astype(np.float64), "frames": frames, "settled": settled,
            "last_move_mm": moved, "move_history_mm": history, "seconds": time.time() - t0}
