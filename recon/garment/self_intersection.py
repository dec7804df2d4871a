"""Where a posed body passes through itself (thigh into belly in deep hip flexion, arm into the
chest).

Linear blend skinning lets body parts interpenetrate in strong flexion. Cloth between two such
parts cannot be outside both, so a cloth collision metric or loss is ill-defined there (thesis
5.4.3 trains and tests PBNS on poses "that do not produce self-collisions").
``SkinSelfIntersection`` finds the surface vertices that lie inside the body: each vertex, moved
``offset`` along its normal, is tested with the generalised winding number of the closed surface
(warp's BVH mesh query, on the CPU). Contacts the rest pose already has
(between the fingers, ears) are not counted, and only the vertices of the garment region (the
skin of the torso, hips, upper legs and arms: the vertices whose dominant bone is not the head,
neck, hands or feet) are tested. Unlike the pose sampler's sphere test (recon.poses.collision:
cheap, conservative, blind to adjacent parts), this one sees the thigh pressing into the belly.
"""
from __future__ import annotations

import numpy as np
import torch
import warp as wp

from recon.body.base import BodyModel
from recon.body.skeleton import JOINT_NAMES
from recon.garment.mesh import largest_component_faces, vertex_normals

# skin that garments never cover: left out of the test (faces and fingers have many rest contacts)
UNCOVERED = ("head", "neck", "wrist", "hand", "ankle", "foot")
wp.config.quiet = True


@wp.kernel
def _inside_sign(mesh: wp.uint64, pts: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
    """The winding-number sign of each point against a closed mesh (compiled on first use, cached by warp)."""
    i = wp.tid()
    out[i] = wp.mesh_query_point_sign_winding_number(mesh, pts[i], 1.0e3).sign


class SkinSelfIntersection:
    """``SkinSelfIntersection(body)(vertices) -> (B, V) bool``: garment-region vertices inside the
    body (and not already so at rest); ``.percent(vertices) -> (B,)`` their share of the region.

    ``body``: a ``recon.body.BodyModel`` (faces, skinning weights, rest pose of ``shape``).
    """

    def __init__(self, body: BodyModel, shape: torch.Tensor | None = None, offset: float = 0.002):
        # the outer skin only: anny also has eyes and a mouth inside the head (closed meshes of their own)
        self.faces = np.ascontiguousarray(largest_component_faces(body.faces.cpu().numpy())).astype(np.int32)
        covered = [j for j, n in enumerate(JOINT_NAMES) if not any(s in n for s in UNCOVERED)]
        bone = body.weights.argmax(1).cpu().numpy()
        self.n_vertices = body.num_vertices
        region = np.zeros(self.n_vertices, bool)
        region[np.unique(self.faces)] = True
        region &= np.isin(bone, covered)
        self.offset = offset
        self.region = np.nonzero(region)[0]
        shape = body.mean_shape[None] if shape is None else shape.reshape(1, -1)
        with torch.no_grad():
            rest = body(body.identity_pose(1), shape).vertices
        self.region = self.region[~self._inside(rest)[0]]  # rest contacts are part of the body's design

    def _inside(self, vertices: torch.Tensor, chunk: int = 64) -> np.ndarray:
        v = torch.as_tensor(vertices, dtype=torch.float32).detach().cpu()
        faces = torch.from_numpy(self.faces).long()
        out = np.zeros((len(v), len(self.region)), bool)
        idx = wp.array(self.faces.ravel(), dtype=int, device="cpu")
        res = wp.zeros(len(self.region), dtype=float, device="cpu")
        for c in range(0, len(v), chunk):  # normals of a few thousand poses at once would take GBs
            vc = v[c:c + chunk]
            probe = (vc[:, self.region] + self.offset * vertex_normals(vc, faces)[:, self.region]).numpy()
            for b in range(len(vc)):
                mesh = wp.Mesh(points=wp.array(vc[b].numpy(), dtype=wp.vec3, device="cpu"), indices=idx)
                wp.launch(_inside_sign, dim=len(self.region), device="cpu",
                          inputs=[mesh.id, wp.array(probe[b], dtype=wp.vec3, device="cpu"), res])
                out[c + b] = res.numpy() < 0
        return out

    def __call__(self, vertices: torch.Tensor) -> torch.Tensor:
        """(B, V, 3) posed vertices, metres -> (B, V) bool."""
        mask = torch.zeros(vertices.shape[0], self.n_vertices, dtype=torch.bool)
        mask[:, torch.from_numpy(self.region)] = torch.from_numpy(self._inside(vertices))
        return mask

    def percent(self, vertices: torch.Tensor) -> torch.Tensor:
        """(B,) % of the garment region's vertices inside the body."""
        return torch.from_numpy(self._inside(vertices).mean(1) * 100.0).float()
