"""``NCSTrainConfig``: every setting of NCS training (``recon garment train --model ncs``). How each
default was chosen, with the runs that chose it: the garment model card's NCS history."""
from __future__ import annotations

from dataclasses import dataclass, field

from recon.garment import losses
from recon.garment.integrate import IntegrateConfig
from recon.garment.losses import FABRIC  # NCS trains on the fabric its PBNS was trained with
from recon.garment.ncs.model import NCSConfig


@dataclass
class NCSTrainConfig:
    outfit: str = "tshirt-skirt"
    # the teacher: chunks of the train split's motion, the cloth integrated through them
    chunk: int = 120  # frames of motion per integrated trajectory (4 s at 30 fps)
    settle: int = 20  # frames on a chunk's first pose held still, before it
    lead: int = 20  # a chunk's first frames, not learnt from: its swing builds up from rest
    chunks: int = 50  # train chunks (x2 with their mirror images)
    stops: float = 0.3  # share of train chunks whose body stops dead halfway (cloth swings on most there)
    val_chunks: int = 4  # chunks of the val performers (as many stopping), to select the checkpoint
    workers: int = 2  # processes integrating chunks
    # edges as stiff across as along in the solver's preconditioner: factorised once, not each frame
    integrate: IntegrateConfig = field(default_factory=lambda: IntegrateConfig(iterations=20, across=1.0))
    mirror: bool = True  # the chunks' left-right mirror images train too (pose mirroring, 6.4.4)
    smooth_motion: float = 1.5  # Gaussian sigma (frames) of the motions: mocap jitter is no motion
    # a solved chunk with an edge this much longer or shorter (m) than at rest went wrong (the cloth
    # caught between the legs, or the solver lost it): dropped from training
    max_strain: float = 0.035
    # the solved offsets are unposed with the blended skinning rotations' singular values clamped from
    # below at this (integrate.unpose): blends between the legs are near singular
    min_singular: float = 0.2
    # an outfit without pins (a dress, a jumpsuit) swings below the waist only, its top held to PBNS
    waist_hold: bool = True
    # cloth below the rest body's ankles + this (m) stays PBNS's (long trousers' cuffs lie on the feet,
    # whose rotations the descriptors drop), rising to the whole solved displacement over as much again
    ankle_hold: float = 0.08
    # the fitting: the networks learn the teacher's coefficients on D's new rows
    steps: int = 3000
    batch: int = 16  # chunks per step
    lr: float = 3e-3
    weight_decay: float = 0.01
    # keep the predicted hanging part out of the body at ``contact_frames`` of every 4th frame of each
    # chunk (``ncs.losses.Contact``), per mean squared penetration past the collision eps. 0: off
    contact_weight: float = 0.0
    contact_frames: int = 8
    # the physics steps: the thesis' loss on the predictions (``ncs.losses.Physics``) joins the fitting
    physics_steps: int = 200
    physics_chunks: int = 4  # chunks per step
    physics_frames: int = 8  # frames per chunk
    physics_lr: float = 1e-3
    # D's new rows (the fields) learn in the physics steps too, on the hanging part only, as the
    # thesis' decoder does. 0: the principal fields stay
    field_lr: float = 1e-3
    # PBNS's own loss on NCS's static part at poses of the train split (``ncs.losses.StaticPoses``)
    static_poses: int = 1000
    static_batch: int = 8
    static_weight: float = 1.0
    # the energies every cloth state keeps low (collision, edge, pin) on motions no teacher solved
    # (``ncs.losses.FreeMotion``). 0: off
    free_windows: int = 200
    free_batch: int = 4
    free_frames: int = 8
    free_weight: float = 3.0
    seed: int = 0
    model: NCSConfig = field(default_factory=lambda: NCSConfig(hidden=128, static_hidden=256,
                                                                joint_features=16, dynamic=96))
    edge: losses.EdgeConfig = field(default_factory=lambda: FABRIC.edge)
    bend: losses.BendConfig = field(default_factory=lambda: FABRIC.bend)
    collision: losses.CollisionConfig = field(default_factory=lambda: FABRIC.collision)
    gravity: losses.GravityConfig = field(default_factory=lambda: FABRIC.gravity)
    pin: losses.PinConfig = field(default_factory=lambda: FABRIC.pin)
    inertia: losses.InertiaConfig = field(
        default_factory=lambda: losses.InertiaConfig(weight=FABRIC.gravity.weight / 9.81))
