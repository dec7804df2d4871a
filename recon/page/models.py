"""The page's 3D models: small glTF binaries the browser can show, each written as a script.

A page opened from the file system cannot fetch files beside it (browsers give file:// pages an
opaque origin), so each model is a ``.recon-page/models/<id>.js`` that calls ``RECON_MODEL(id, base64)``; the page
loads it as a classic script when its viewer scrolls into view. What goes in a model:

- a photo's result (``static_glb``): the meshes of body.obj / outfit.obj as they are, turned from
  the camera frame (y down, z forward) to glTF's (y up, z towards the viewer). Exactly the OBJ's
  vertices, a fraction of the rigged .glb's size (no skin, no blend shapes).
- an animation (``slim_glb``): the animated .glb without its morph targets, with the four
  strongest skinning influences per vertex, renormalised (three.js uses four), and in place (the
  path over the ground taken out). The cloth then follows the skeleton without its per-frame
  deformation; the .glb itself has it, and the path.
"""
from __future__ import annotations

import base64
import hashlib
import json
import os
import struct
from pathlib import Path

import numpy as np
import trimesh

from recon import paths
from recon.export.glb import BIN_CHUNK, GLB_MAGIC, JSON_CHUNK, glb_bytes

CAMERA_TO_GLTF = np.diag([1.0, -1.0, -1.0])  # OpenCV camera axes -> glTF's (a 180 degree turn about x)
FORMAT = 3  # part of every model's id: a page written by a recon that makes models differently remakes them
COLOURS = {"body": (0.55, 0.52, 0.50, 1.0), "outfit": (0.22, 0.40, 0.75, 1.0)}


def model_id(files: list[Path], kind: str, root: Path) -> str:
    """A model's name: its kind and its sources' paths (from the page's folder: a moved folder
    keeps its models), sizes and times (a changed file, a new id)."""
    h = hashlib.sha256(f"{FORMAT}|{kind}".encode())
    for f in files:
        st = f.stat()
        h.update(f"{os.path.relpath(f, root)}|{st.st_size}|{st.st_mtime_ns}".encode())
    return h.hexdigest()[:16]


def static_glb(objs: dict[str, Path]) -> bytes:
    """OBJ meshes in the camera frame -> one glb in glTF's frame; ``objs``: name -> path, the
    name choosing the colour (COLOURS, "outfit" for anything but "body")."""
    scene = trimesh.Scene()
    for name, path in objs.items():
        mesh = trimesh.load(path, force="mesh", process=False)
        mesh = trimesh.Trimesh(np.asarray(mesh.vertices) @ CAMERA_TO_GLTF, np.asarray(mesh.faces), process=False)
        colour = COLOURS.get(name, COLOURS["outfit"])
        mesh.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
            name=name, baseColorFactor=colour, metallicFactor=0.0, roughnessFactor=0.8, doubleSided=True))
        scene.add_geometry(mesh, geom_name=name)
    return scene.export(file_type="glb", include_normals=True)


def read_glb(data: bytes) -> tuple[dict, bytes]:
    """A glb's JSON and binary chunk."""
    magic, _, _ = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC:
        raise ValueError("not a binary glTF file")
    n, kind = struct.unpack_from("<II", data, 12)
    if kind != JSON_CHUNK:
        raise ValueError("a glb's first chunk must be its JSON")
    gltf = json.loads(data[20:20 + n])
    off = 20 + n
    binary = b""
    if off + 8 <= len(data):
        m, kind = struct.unpack_from("<II", data, off)
        if kind == BIN_CHUNK:
            binary = data[off + 8:off + 8 + m]
    return gltf, binary


def slim_glb(data: bytes) -> bytes:
    """An animated glb without morph targets (and their weight animation), with only its first
    JOINTS/WEIGHTS set (recon writes the strongest influences first), renormalised, and in place:
    the root's path over the ground is taken out (a viewer keeps the person in view; the height
    and every turn stay). Unused data is dropped."""
    gltf, binary = read_glb(data)
    for mesh in gltf.get("meshes", []):
        mesh.pop("weights", None)
        mesh.get("extras", {}).pop("targetNames", None)
        for prim in mesh["primitives"]:
            prim.pop("targets", None)
            for key in [k for k in prim["attributes"] if k.split("_")[0] in ("JOINTS", "WEIGHTS")]:
                if not key.endswith("_0"):
                    del prim["attributes"][key]
    binary = bytearray(binary)
    for mesh in gltf.get("meshes", []):
        for prim in mesh["primitives"]:
            if "WEIGHTS_0" in prim["attributes"]:
                _rewrite(gltf, binary, prim["attributes"]["WEIGHTS_0"], 4,
                         lambda w: w / np.maximum(w.sum(1, keepdims=True), 1e-12))
    children = {c for n in gltf.get("nodes", []) for c in n.get("children", [])}
    for anim in gltf.get("animations", []):
        for c in anim["channels"]:
            if c["target"].get("path") == "translation" and c["target"].get("node") not in children:
                _rewrite(gltf, binary, anim["samplers"][c["sampler"]]["output"], 3, lambda t: t * [0.0, 1.0, 0.0])
    for anim in gltf.get("animations", []):
        keep = [c for c in anim["channels"] if c["target"].get("path") != "weights"]
        samplers = sorted({c["sampler"] for c in keep})
        remap = {s: i for i, s in enumerate(samplers)}
        anim["samplers"] = [anim["samplers"][s] for s in samplers]
        anim["channels"] = [{**c, "sampler": remap[c["sampler"]]} for c in keep]
    return glb_bytes(*_repack(gltf, binary))


def _rewrite(gltf: dict, binary: bytearray, index: int, width: int, change) -> None:
    """Replace a float accessor's values (count, ``width``) by ``change(values)``, as a new buffer
    view at the end of ``binary`` (views may be shared)."""
    acc = gltf["accessors"][index]
    if acc["componentType"] != 5126 or "bufferView" not in acc:
        return
    view = gltf["bufferViews"][acc["bufferView"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    values = np.frombuffer(bytes(binary[start:start + acc["count"] * width * 4]), np.float32).reshape(-1, width)
    values = np.ascontiguousarray(change(values), dtype=np.float32)
    binary += b"\0" * (-len(binary) % 4)
    gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": values.nbytes,
                                **({"target": view["target"]} if "target" in view else {})})
    binary += values.tobytes()
    acc["bufferView"], acc["byteOffset"] = len(gltf["bufferViews"]) - 1, 0
    if "min" in acc:
        acc["min"], acc["max"] = values.min(0).tolist(), values.max(0).tolist()


def _repack(gltf: dict, binary: bytes) -> tuple[dict, bytes]:
    """Keep only the accessors and buffer views something still refers to; one buffer."""
    used: list[int] = []

    def use(i):
        if i not in used:
            used.append(i)
    for mesh in gltf.get("meshes", []):
        for prim in mesh["primitives"]:
            for i in prim["attributes"].values():
                use(i)
            if "indices" in prim:
                use(prim["indices"])
    for skin in gltf.get("skins", []):
        if "inverseBindMatrices" in skin:
            use(skin["inverseBindMatrices"])
    for anim in gltf.get("animations", []):
        for s in anim["samplers"]:
            use(s["input"])
            use(s["output"])
    amap = {old: new for new, old in enumerate(used)}
    accessors = [gltf["accessors"][i] for i in used]
    views, vmap, out = [], {}, bytearray()
    for acc in accessors:
        v = acc.get("bufferView")
        if v is None or v in vmap:
            continue
        view = dict(gltf["bufferViews"][v])
        start = view.get("byteOffset", 0)
        out += b"\0" * (-len(out) % 4)
        view.update(buffer=0, byteOffset=len(out))
        out += binary[start:start + view["byteLength"]]
        vmap[v] = len(views)
        views.append(view)
    for acc in accessors:
        if "bufferView" in acc:
            acc["bufferView"] = vmap[acc["bufferView"]]
    for mesh in gltf.get("meshes", []):
        for prim in mesh["primitives"]:
            prim["attributes"] = {k: amap[i] for k, i in prim["attributes"].items()}
            if "indices" in prim:
                prim["indices"] = amap[prim["indices"]]
    for skin in gltf.get("skins", []):
        if "inverseBindMatrices" in skin:
            skin["inverseBindMatrices"] = amap[skin["inverseBindMatrices"]]
    for anim in gltf.get("animations", []):
        for s in anim["samplers"]:
            s["input"], s["output"] = amap[s["input"]], amap[s["output"]]
    gltf.update(accessors=accessors, bufferViews=views, buffers=[{"byteLength": len(out) + (-len(out) % 4)}])
    return gltf, bytes(out)


def write_model_script(path: Path, mid: str, glb: bytes) -> None:
    """The model as a script the page loads from the file system (module doc)."""
    paths.write_text(path, f'RECON_MODEL("{mid}","{base64.b64encode(glb).decode()}");\n')
