"""Rigged glTF 2.0 (.glb) of a body, dressed or not, in one pose or animated, written without
extra dependencies: one skeleton (the 24 named joints, SMPL order), the body and an outfit as
skinned meshes (the 4 strongest joint influences per vertex, renormalised: what three.js, Unity and
most engines read; ``influences=None`` keeps every one: anny's skinning exactly), the outfit's
deformations as morph targets with per-frame weights (``BlendAnimation``: what
``recon.garment.morph`` makes of a Dresser's outfit). Vertex order is the body model's.

The joints' node rotations hold the first frame's pose, so a client that reads no animation
(Blender's armature in edit mode excepted) shows the posed body; with more than one frame an
animation drives the rotations, the root translation and the morph weights.

Frame: glTF's, +Y up, metres. ``recon run`` writes its files in the view frame of the photo's
camera (the camera at the origin looking down -Z, which is glTF's camera convention) and adds
that camera; ``recon animate`` and the demos write the body frame (+Z forward).
"""
from __future__ import annotations

import json
import math
import struct
from pathlib import Path
from typing import NamedTuple

import numpy as np
import roma
import torch
import trimesh

from recon import paths
from recon.body import skeleton
from recon.body.base import BodyModel

FLOAT, UBYTE, USHORT, UINT = 5126, 5121, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
GLB_MAGIC, JSON_CHUNK, BIN_CHUNK = 0x46546C67, 0x4E4F534A, 0x004E4942  # "glTF", "JSON", "BIN\0"
BODY_RGBA = (0.8, 0.72, 0.66, 1.0)
OUTFIT_RGBA = (0.3, 0.45, 0.75, 1.0)
INFLUENCES = 4  # joints per vertex by default: one JOINTS_0 / WEIGHTS_0 set, which every engine reads


class BlendAnimation(NamedTuple):
    """An outfit animated in glTF's terms: rest vertices (N, 3), faces (F, 3), skin weights (N, 24),
    morph targets (K, N * 3) or (K, N, 3) and their weights per frame (T, K); arrays or tensors."""
    rest: np.ndarray | torch.Tensor
    faces: np.ndarray | torch.Tensor
    weights: np.ndarray | torch.Tensor
    targets: np.ndarray | torch.Tensor
    codes: np.ndarray | torch.Tensor


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


def influence_sets(weights: np.ndarray, most: int | None = INFLUENCES) -> list[tuple[np.ndarray, np.ndarray]]:
    """Skinning weights (N, J) -> glTF's JOINTS_n / WEIGHTS_n pairs of 4: each vertex's ``most``
    strongest influences (None: all of them; as many sets as the most influenced vertex needs),
    renormalised to sum to 1."""
    n_inf = int(max(1, (weights > 1e-6).sum(1).max()))
    k = 4 * math.ceil((n_inf if most is None else min(n_inf, most)) / 4)
    idx = np.argsort(-weights, 1, kind="stable")[:, :k]
    w = np.take_along_axis(weights, idx, 1)
    w = np.where(w > 1e-6, w, 0.0)
    if most is not None and most < k:
        w[:, most:] = 0.0
    w = w / w.sum(1, keepdims=True)
    idx = np.where(w > 0, idx, 0)  # unused slots point at joint 0 with weight 0
    return [(idx[:, s:s + 4].astype(np.uint16), w[:, s:s + 4].astype(np.float32)) for s in range(0, k, 4)]


def written_weights(weights: np.ndarray | torch.Tensor, most: int | None = INFLUENCES) -> torch.Tensor:
    """The (N, J) weights a glTF reader skins with, where ``influence_sets(weights, most)`` wrote them."""
    weights = np.asarray(weights.detach() if torch.is_tensor(weights) else weights)
    out = np.zeros(weights.shape, np.float32)
    rows = np.arange(len(weights))[:, None].repeat(4, 1)
    for j, w in influence_sets(weights, most):
        np.add.at(out, (rows, j.astype(np.int64)), w)
    return torch.from_numpy(out)


def _array(a) -> np.ndarray:
    return a.detach().cpu().numpy() if torch.is_tensor(a) else np.asarray(a)


def _quat_xyzw(r: torch.Tensor) -> np.ndarray:
    return roma.rotmat_to_unitquat(r).numpy().astype(np.float32)  # roma: (x, y, z, w) like glTF


def write_glb(path: str | Path, body: BodyModel, shape: torch.Tensor, rotmats: torch.Tensor, transl: torch.Tensor,
              fps: float = 30.0, outfit: BlendAnimation | None = None,
              camera: tuple[np.ndarray, tuple[int, int]] | None = None, animation_name: str = "motion",
              influences: int | None = INFLUENCES) -> Path:
    """Write a rigged .glb atomically.

    Args:
        shape: (S,) or (1, S) the body's shape parameters.
        rotmats: (T, 24, 3, 3) local joint rotations; the root's is into the file's frame.
        transl: (T, 3) pelvis positions in the file's frame, metres.
        outfit: a skinned outfit with its morph targets and their weights per frame
            (``recon.garment.morph.outfit_animation`` makes it from a Dresser).
        camera: (K, (height, width)): a perspective camera at the origin looking down -Z with the
            vertical field of view of K (glTF has no principal point: it is taken as centred).
        influences: joints per vertex kept (the strongest, renormalised); None: every one.
    With T = 1 the file holds the pose and no animation."""
    shape = shape.reshape(1, -1)
    rotmats, transl = rotmats.detach().float().cpu(), transl.detach().float().cpu().reshape(-1, 3)
    if rotmats.ndim != 4 or rotmats.shape[1:] != (24, 3, 3) or len(transl) != len(rotmats):
        raise ValueError("rotmats must be (T, 24, 3, 3) with one pelvis position per frame")
    with torch.no_grad():
        rest_v, rest_j = body.rest_geometry(shape.to(body.mean_shape))
    rest_v, rest_j = rest_v[0].numpy().astype(np.float32), rest_j[0].numpy().astype(np.float32)
    parents = skeleton.JOINT_PARENTS
    t = len(rotmats)
    q = _quat_xyzw(rotmats.reshape(-1, 3, 3)).reshape(t, 24, 4)
    buf = _Buffer()
    nodes, meshes, materials = [], [], []

    # skeleton: node k = joint k, translation = rest offset to the parent, rotation = the pose
    for k, name in enumerate(skeleton.JOINT_NAMES):
        off = transl[0].numpy() if parents[k] < 0 else rest_j[k] - rest_j[parents[k]]
        node = {"name": name, "translation": np.asarray(off, float).tolist(),
                "rotation": q[0, k].astype(float).tolist()}
        children = [c for c in range(24) if parents[c] == k]
        if children:
            node["children"] = children
        nodes.append(node)
    ibm = np.tile(np.eye(4, dtype=np.float32), (24, 1, 1))
    ibm[:, :3, 3] = -rest_j
    ibm_acc = buf.add(ibm.transpose(0, 2, 1).reshape(24, 16), FLOAT, "MAT4")  # column-major
    skin = {"name": "skeleton", "joints": list(range(24)), "inverseBindMatrices": ibm_acc, "skeleton": 0}

    def skinned_mesh(name, v, f, weights, rgba, targets=None, morph0=None):
        normals = trimesh.Trimesh(v, f, process=False).vertex_normals.astype(np.float32)
        attrs = {"POSITION": buf.add(v.astype(np.float32), FLOAT, "VEC3", ARRAY_BUFFER, minmax=True),
                 "NORMAL": buf.add(normals, FLOAT, "VEC3", ARRAY_BUFFER)}
        for s, (j, w) in enumerate(influence_sets(weights, influences)):
            attrs[f"JOINTS_{s}"] = buf.add(j, USHORT, "VEC4", ARRAY_BUFFER)
            attrs[f"WEIGHTS_{s}"] = buf.add(w, FLOAT, "VEC4", ARRAY_BUFFER)
        prim = {"attributes": attrs, "material": len(materials),
                "indices": buf.add(f.astype(np.uint32).reshape(-1), UINT, "SCALAR", ELEMENT_ARRAY_BUFFER)}
        materials.append({"name": name, "pbrMetallicRoughness": {"baseColorFactor": list(rgba), "metallicFactor": 0.0,
                                                                  "roughnessFactor": 0.8}, "doubleSided": True})
        mesh = {"name": name, "primitives": [prim]}
        if targets is not None:
            prim["targets"] = [{"POSITION": buf.add(d.astype(np.float32), FLOAT, "VEC3", ARRAY_BUFFER, minmax=True)}
                               for d in targets]
            mesh["weights"] = morph0.astype(float).tolist()
        meshes.append(mesh)
        nodes.append({"name": name, "mesh": len(meshes) - 1, "skin": 0})
        return len(nodes) - 1

    mesh_nodes = [skinned_mesh("body", rest_v, body.faces.numpy(), body.weights.numpy(), BODY_RGBA)]
    morph = None
    if outfit is not None:
        morph = _array(outfit.codes).astype(np.float32)  # (T, K)
        mesh_nodes.append(skinned_mesh("outfit", _array(outfit.rest), _array(outfit.faces), _array(outfit.weights),
                                       OUTFIT_RGBA, targets=_array(outfit.targets).reshape(len(morph[0]), -1, 3),
                                       morph0=morph[0]))
    scene_nodes = [0] + mesh_nodes
    doc = {"asset": {"version": "2.0", "generator": "recon"}, "scene": 0}
    if camera is not None:
        k, (h, w) = camera
        doc["cameras"] = [{"type": "perspective", "name": "photo", "perspective": {
            "yfov": float(2 * math.atan(0.5 * h / float(k[1][1]))), "aspectRatio": float(w / h),
            "znear": 0.01, "zfar": 1000.0}}]
        nodes.append({"name": "photo camera", "camera": 0})
        scene_nodes.append(len(nodes) - 1)

    if t > 1:  # per-joint rotations, root translation, outfit morph weights
        times = buf.add((np.arange(t, dtype=np.float32) / fps)[:, None], FLOAT, "SCALAR", minmax=True)
        samplers, channels = [], []
        for k in range(24):
            samplers.append({"input": times, "output": buf.add(q[:, k], FLOAT, "VEC4"), "interpolation": "LINEAR"})
            channels.append({"sampler": len(samplers) - 1, "target": {"node": k, "path": "rotation"}})
        samplers.append({"input": times, "output": buf.add(transl.numpy(), FLOAT, "VEC3"), "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": 0, "path": "translation"}})
        if morph is not None:
            samplers.append({"input": times, "output": buf.add(morph.reshape(-1, 1), FLOAT, "SCALAR"),
                             "interpolation": "LINEAR"})
            channels.append({"sampler": len(samplers) - 1, "target": {"node": mesh_nodes[1], "path": "weights"}})
        doc["animations"] = [{"name": animation_name, "samplers": samplers, "channels": channels}]

    doc |= {"scenes": [{"nodes": scene_nodes}], "nodes": nodes, "meshes": meshes, "materials": materials,
            "skins": [skin], "buffers": [{"byteLength": len(buf.data)}], "bufferViews": buf.views,
            "accessors": buf.accessors}
    glb = glb_bytes(doc, bytes(buf.data))
    paths.atomic_write(Path(path), lambda tmp: Path(tmp).write_bytes(glb))
    return Path(path)


def glb_bytes(doc: dict, binary: bytes) -> bytes:
    """A binary glTF file: the JSON chunk (space-padded) and the binary chunk (zero-padded)."""
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    binary += b"\0" * (-len(binary) % 4)
    return (struct.pack("<III", GLB_MAGIC, 2, 12 + 8 + len(js) + 8 + len(binary))
            + struct.pack("<II", len(js), JSON_CHUNK) + js + struct.pack("<II", len(binary), BIN_CHUNK) + binary)
