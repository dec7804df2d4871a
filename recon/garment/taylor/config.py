"""The Taylor model's build settings (``recon garment train --model taylor``)."""
from __future__ import annotations

from dataclasses import dataclass, field

from recon.garment.drape import DrapeSolverConfig
from recon.garment.taylor.model import BlendConfig

# the phenotype box the database's bodies span (anny: gender, age, muscle, weight, height, proportions)
SHAPE_BOX = ((0.0, 1.0), (0.3, 1.0), (0.1, 0.9), (0.05, 0.95), (0.05, 0.95), (0.2, 0.8))


@dataclass
class PoseFitConfig:
    """PBNS trained further on unposed drapes on its body (the examples' and ``poses`` more), its
    blend weights (its skinning) kept: "adam", its network (widened to ``hidden``) and blend shapes
    by minibatch Adam on the mean vertex distance; "ridge", its blend shapes alone, a least-squares
    fit on its codes pulled towards PBNS's by ``ridge``."""
    method: str = "adam"
    steps: int = 2000  # adam; 0: PBNS as trained is the pose model
    lr: float = 3e-4
    batch: int = 96
    seed: int = 0
    ridge: float = 1.0  # ridge: the L2 weight on the change of the blend shapes (per code, squared)
    poses: int = 1024  # more train poses draped on the pose model's body for the fit alone (not corrections)
    hidden: int = 512  # adam: units per hidden layer of the fitted network (0: PBNS's; more: PBNS's widened)
    corrections: bool = False  # the fitted model corrected at the examples (PBNS as trained always is)

    @property
    def trains(self) -> bool:
        """Whether the pose model is fitted at all (else PBNS as trained)."""
        return self.method != "adam" or self.steps > 0


@dataclass
class TaylorBuildConfig:
    outfit: str = "tshirt-skirt"
    anchors: int = 64  # the paper: ~150; 64 x 9 drapes fit the 45-min budget on 2 cores
    shapes: int = 8  # bodies per anchor besides the pose model's (the paper: 17)
    pose_examples: int = 512  # poses draped on the pose model's body alone, besides the anchors
    components: int = 5  # PCA components of a shape model (the paper: 5, 98.6 % of the variance)
    # L2 weight of the shape-to-coefficient map on standardised phenotypes; None: the one of RIDGES
    # with the least leave-one-body-out error over the anchors' drapes (the paper: 0.2 on SMPL betas)
    ridge: float | None = None
    frame_step: int = 4  # mocap frames between sampled poses (the paper: every 4th)
    sensitivity_poses: int = 8  # poses x 3 bodies the sensitivity is averaged over
    sensitivity_step: float = 0.05  # rad, central differences
    shape_rounds: int = 2  # drape rounds for the other bodies (they start near their minimum)
    seed: int = 0
    workers: int = 2
    drape: DrapeSolverConfig = field(default_factory=DrapeSolverConfig)
    blend: BlendConfig = field(default_factory=BlendConfig)
    pose_fit: PoseFitConfig = field(default_factory=PoseFitConfig)
