"""Animated glTF 2.0 (.glb) of a dressed body on a pose sequence, written without extra
dependencies: one skeleton (24 joints, SMPL order), the body and the outfit as skinned meshes
(4 influences per vertex), the outfit's PBNS deformations as morph targets (the rows of D) whose
weights are the per-frame embedding X(theta_t) - PBNS is skinning + PSD, which glTF runs natively.

Frame: glTF is +Y up, metres, like the body frame (+Z forward). Loadable by trimesh and by
standard viewers (Blender, three.js, model-viewer).
"""
from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import roma
import torch

from recon import paths
from recon.body import skeleton
from recon.garment.pbns import pose_features

FLOAT, UBYTE, USHORT, UINT = 5126, 5121, 5123, 5125


class _Buffer:
    def __init__(self):
        self.data = bytearray()
        self.views, self.accessors = [], []

    def add(self, a: np.ndarray, ctype: int, kind: str, target: int | None = None, minmax: bool = False) -> int:
        raw = np.ascontiguousarray(a).tobytes()
        self.data += b"\0" * (-len(self.data) % 4)
        view = {"buffer": 0, "byteOffset": len(self.data), "byteLength": len(raw)}
        if target:
            view["target"] = target
        self.data += raw
        self.views.append(view)
        acc = {"bufferView": len(self.views) - 1, "componentType": ctype, "count": int(a.shape[0]), "type": kind}
        if minmax:
            acc["min"] = np.asarray(a).min(0).astype(float).tolist()
            acc["max"] = np.asarray(a).max(0).astype(float).tolist()
        self.accessors.append(acc)
        return len(self.accessors) - 1


def _top4(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    idx = np.argsort(-weights, 1)[:, :4]
    w = np.take_along_axis(weights, idx, 1)
    w = w / w.sum(1, keepdims=True)
    return idx.astype(np.uint16), w.astype(np.float32)


def _quat_xyzw(r: torch.Tensor) -> np.ndarray:
    return roma.rotmat_to_unitquat(r).numpy().astype(np.float32)  # roma: (x, y, z, w) like glTF


def write_animated_glb(path: Path, body, shape: torch.Tensor, rotmats: torch.Tensor, transl: torch.Tensor,
                       fps: float, dresser=None) -> Path:
    """rotmats (T, 24, 3, 3) local rotations, transl (T, 3) pelvis positions, body frame."""
    shape = shape.reshape(1, -1)
    with torch.no_grad():
        rest_v, rest_j = body.rest_geometry(shape.to(body.mean_shape))
    rest_v, rest_j = rest_v[0].numpy().astype(np.float32), rest_j[0].numpy().astype(np.float32)
    parents = skeleton.JOINT_PARENTS
    buf = _Buffer()
    nodes, meshes = [], []

    # skeleton: node k = joint k, translation = rest offset to the parent, rotation animated
    for k, name in enumerate(skeleton.JOINT_NAMES):
        off = rest_j[k] - (rest_j[parents[k]] if parents[k] >= 0 else 0.0)
        children = [c for c in range(24) if parents[c] == k]
        node = {"name": name, "translation": off.astype(float).tolist()}
        if children:
            node["children"] = children
        nodes.append(node)
    ibm = np.tile(np.eye(4, dtype=np.float32), (24, 1, 1))
    ibm[:, :3, 3] = -rest_j
    ibm_acc = buf.add(ibm.transpose(0, 2, 1).reshape(24, 16), FLOAT, "MAT4")  # column-major
    skin = {"joints": list(range(24)), "inverseBindMatrices": ibm_acc, "skeleton": 0}

    def skinned_mesh(name, v, f, weights, rgba, targets=None):
        j4, w4 = _top4(weights)
        attrs = {"POSITION": buf.add(v.astype(np.float32), FLOAT, "VEC3", 34962, minmax=True),
                 "JOINTS_0": buf.add(j4, USHORT, "VEC4", 34962), "WEIGHTS_0": buf.add(w4, FLOAT, "VEC4", 34962)}
        prim = {"attributes": attrs, "indices": buf.add(f.astype(np.uint32).reshape(-1), UINT, "SCALAR", 34963),
                "material": len(materials)}
        materials.append({"name": name, "pbrMetallicRoughness": {"baseColorFactor": list(rgba), "metallicFactor": 0.0,
                                                                  "roughnessFactor": 0.8}, "doubleSided": True})
        mesh = {"name": name, "primitives": [prim]}
        if targets is not None:
            prim["targets"] = [{"POSITION": buf.add(t.astype(np.float32), FLOAT, "VEC3", 34962, minmax=True)}
                               for t in targets]
            mesh["weights"] = [0.0] * len(targets)
        meshes.append(mesh)
        nodes.append({"name": name, "mesh": len(meshes) - 1, "skin": 0})
        return len(nodes) - 1

    materials: list = []
    mesh_nodes = [skinned_mesh("body", rest_v, body.faces.numpy(), body.weights.numpy(), (0.8, 0.72, 0.66, 1.0))]
    morph_weights = None
    if dresser is not None:
        model = dresser.model
        rest_c = dresser.rest_for(body, shape[0]).numpy()
        d = model.D.detach().numpy().reshape(model.cfg.embedding, -1, 3)
        mesh_nodes.append(skinned_mesh("outfit", rest_c, model.faces.numpy(), model.weights.detach().numpy(),
                                       (0.3, 0.45, 0.75, 1.0), targets=d))
        with torch.no_grad():
            morph_weights = model.mlp(pose_features(rotmats)).numpy().astype(np.float32)  # (T, |X|)

    # animation: per-joint rotations, root translation, outfit morph weights
    t = len(rotmats)
    times = buf.add((np.arange(t, dtype=np.float32) / fps)[:, None], FLOAT, "SCALAR", minmax=True)
    samplers, channels = [], []
    q = _quat_xyzw(rotmats.reshape(-1, 3, 3)).reshape(t, 24, 4)
    for k in range(24):
        samplers.append({"input": times, "output": buf.add(q[:, k], FLOAT, "VEC4"), "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": k, "path": "rotation"}})
    samplers.append({"input": times, "output": buf.add(transl.numpy().astype(np.float32), FLOAT, "VEC3"),
                     "interpolation": "LINEAR"})
    channels.append({"sampler": len(samplers) - 1, "target": {"node": 0, "path": "translation"}})
    if morph_weights is not None:
        samplers.append({"input": times, "output": buf.add(morph_weights.reshape(-1, 1), FLOAT, "SCALAR"),
                         "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": mesh_nodes[1], "path": "weights"}})

    doc = {"asset": {"version": "2.0", "generator": "recon"}, "scene": 0,
           "scenes": [{"nodes": [0] + mesh_nodes}], "nodes": nodes, "meshes": meshes, "materials": materials,
           "skins": [skin], "animations": [{"name": "mocap", "samplers": samplers, "channels": channels}],
           "buffers": [{"byteLength": len(buf.data)}], "bufferViews": buf.views, "accessors": buf.accessors}
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    bin_ = bytes(buf.data) + b"\0" * (-len(buf.data) % 4)
    glb = struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(js) + 8 + len(bin_))
    glb += struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(bin_), 0x004E4942) + bin_
    paths.atomic_write(Path(path), lambda tmp: Path(tmp).write_bytes(glb))
    return Path(path)
