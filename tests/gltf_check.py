"""Reading our .glb files the way a client does: the Khronos glTF validator (node package
gltf-validator, installed by scripts/setup.sh) and a small evaluator of nodes, skins and morph
targets that poses the meshes as a viewer would."""
from __future__ import annotations

import json
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
import roma
import torch

ROOT = Path(__file__).resolve().parents[1]
VALIDATOR = ROOT / ".venv" / "gltf-validator" / "node_modules" / "gltf-validator"
SCRIPT = """
const v = require(process.argv[1]);
const data = require('fs').readFileSync(process.argv[2]);
v.validateBytes(new Uint8Array(data), {maxIssues: 50}).then(r => console.log(JSON.stringify(r.issues)))
  .catch(e => { console.error(String(e)); process.exit(2); });
"""


def validate(path: Path) -> dict:
    """The validator's issue summary (numErrors, numWarnings, messages); skips the test where node or
    the package is missing (scripts/setup.sh installs the package where npm exists)."""
    node = shutil.which("node")
    if node is None or not VALIDATOR.exists():
        pytest.skip("the Khronos glTF validator needs node and `npm install gltf-validator` (scripts/setup.sh)")
    out = subprocess.run([node, "-e", SCRIPT, str(VALIDATOR), str(path)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def assert_valid(path: Path) -> dict:
    issues = validate(path)
    errors = [m for m in issues["messages"] if m["severity"] == 0]
    warnings = [m for m in issues["messages"] if m["severity"] == 1]
    assert issues["numErrors"] == 0 and not errors, errors
    assert issues["numWarnings"] == 0 and not warnings, warnings
    return issues


def read_glb(path: Path):
    raw = Path(path).read_bytes()
    jl = struct.unpack("<I", raw[12:16])[0]
    doc = json.loads(raw[20:20 + jl])
    binary = raw[20 + jl + 8:]
    sizes = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}
    dtypes = {5126: np.float32, 5123: np.uint16, 5125: np.uint32}

    def acc(i):
        a = doc["accessors"][i]
        v = doc["bufferViews"][a["bufferView"]]
        arr = np.frombuffer(binary, dtypes[a["componentType"]], a["count"] * sizes[a["type"]], v["byteOffset"])
        return arr.reshape(a["count"], sizes[a["type"]]) if sizes[a["type"]] > 1 else arr
    return doc, acc


def pose_meshes(path: Path, frame: int | None = None) -> dict[str, np.ndarray]:
    """Every skinned mesh of the file posed as a viewer would: node TRS (frame ``frame`` of the
    first animation, or the nodes' own values when None), skin with all JOINTS_n/WEIGHTS_n sets,
    morph targets with the animated or the mesh's default weights. Name -> (N, 3)."""
    doc, acc = read_glb(path)
    nodes = doc["nodes"]
    local = []
    for n in nodes:
        m = np.eye(4)
        m[:3, 3] = n.get("translation", [0, 0, 0])
        if "rotation" in n:
            m[:3, :3] = roma.unitquat_to_rotmat(torch.tensor(n["rotation"], dtype=torch.float64)).numpy()
        local.append(m)
    morph = {}
    if frame is not None:
        anim = doc["animations"][0]
        for ch in anim["channels"]:
            out = acc(anim["samplers"][ch["sampler"]]["output"])
            node, what = ch["target"]["node"], ch["target"]["path"]
            if what == "rotation":
                local[node][:3, :3] = roma.unitquat_to_rotmat(torch.tensor(out[frame], dtype=torch.float64)).numpy()
            elif what == "translation":
                local[node][:3, 3] = out[frame]
            else:
                k = len(doc["meshes"][nodes[node]["mesh"]]["weights"])
                morph[node] = out.reshape(-1, k)[frame]
    parent = {c: i for i, n in enumerate(nodes) for c in n.get("children", [])}
    glob: dict[int, np.ndarray] = {}

    def world(i):
        if i not in glob:
            glob[i] = local[i] if i not in parent else world(parent[i]) @ local[i]
        return glob[i]
    skin = doc["skins"][0]
    ibm = acc(skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
    jm = np.stack([world(j) @ b for j, b in zip(skin["joints"], ibm)])
    posed = {}
    for i, n in enumerate(nodes):
        if "mesh" not in n:
            continue
        mesh = doc["meshes"][n["mesh"]]
        prim = mesh["primitives"][0]
        pos = acc(prim["attributes"]["POSITION"]).astype(np.float64)
        if "targets" in prim:
            w = morph.get(i, mesh.get("weights"))
            pos = pos + sum(m * acc(t["POSITION"]) for m, t in zip(w, prim["targets"]))
        m = np.zeros((len(pos), 4, 4))
        s = 0
        while f"JOINTS_{s}" in prim["attributes"]:
            j, w = acc(prim["attributes"][f"JOINTS_{s}"]), acc(prim["attributes"][f"WEIGHTS_{s}"])
            m += np.einsum("nk,nkij->nij", w, jm[j.astype(int)])
            s += 1
        posed[mesh["name"]] = (m[:, :3, :3] @ pos[..., None])[..., 0] + m[:, :3, 3]
    return posed
