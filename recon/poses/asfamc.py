"""CMU ASF/AMC reader -> SourceMotion.

Node k of the result sits at the START of ASF bone k (the root at the root position) and
carries that bone's world frame; leaf bones get an extra ``<bone>_end`` node at their end.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from recon.errors import ReconError
from recon.poses.motion import SourceMotion


class ASFError(ReconError):
    """The file is not a readable ASF/AMC motion; the message says where."""


def read_asf(path: str | Path) -> dict:
    lines = Path(path).read_text(errors="replace").splitlines()
    bones: dict[str, dict] = {"root": {"direction": np.zeros(3), "length": 0.0, "axis": np.eye(3), "dof": []}}
    hierarchy: dict[str, list[str]] = {}
    root_order, root_axis = ["TX", "TY", "TZ", "RX", "RY", "RZ"], "XYZ"
    section, cur = None, None
    for raw in lines:
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith(":"):
            section = line.split()[0]
            continue
        parts = line.split()
        if section == ":root":
            if parts[0] == "order":
                root_order = [p.upper() for p in parts[1:]]
            elif parts[0] == "axis":
                root_axis = parts[1].upper()
        elif section == ":bonedata":
            if parts[0] == "begin":
                cur = {"dof": []}
            elif parts[0] == "end":
                if "name" not in cur:
                    raise ASFError(f"{path}: bone without a name")
                bones[cur["name"]] = cur
            elif parts[0] == "name":
                cur["name"] = parts[1]
            elif parts[0] == "direction":
                cur["direction"] = np.array([float(v) for v in parts[1:4]])
            elif parts[0] == "length":
                cur["length"] = float(parts[1])
            elif parts[0] == "axis":
                ang = [float(v) for v in parts[1:4]]
                order = parts[4].lower() if len(parts) > 4 else "xyz"
                cur["axis"] = Rotation.from_euler(order, ang, degrees=True).as_matrix()
            elif parts[0] == "dof":
                cur["dof"] = [p.lower() for p in parts[1:]]
        elif section == ":hierarchy" and parts[0] not in ("begin", "end"):
            hierarchy[parts[0]] = parts[1:]
    bones["root"]["order"] = root_order
    bones["root"]["root_axis"] = root_axis
    return {"bones": bones, "hierarchy": hierarchy}


def read_amc(path: str | Path) -> list[dict[str, list[float]]]:
    frames: list[dict[str, list[float]]] = []
    for raw in Path(path).read_text(errors="replace").splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ":")):
            continue
        parts = line.split()
        if parts[0].isdigit() and len(parts) == 1:
            frames.append({})
        elif frames:
            frames[-1][parts[0]] = [float(v) for v in parts[1:]]
    if not frames:
        raise ASFError(f"{path}: no frames")
    return frames


def read_asf_amc(asf_path: str | Path, amc_path: str | Path, fps: float = 120.0) -> SourceMotion:
    skel = read_asf(asf_path)
    bones, hier = skel["bones"], skel["hierarchy"]
    order: list[str] = []
    parent_of: dict[str, str | None] = {"root": None}
    stack = ["root"]
    while stack:  # depth-first so parents precede children
        b = stack.pop()
        order.append(b)
        for c in reversed(hier.get(b, [])):
            if c not in bones:
                raise ASFError(f"{asf_path}: hierarchy names unknown bone {c!r}")
            parent_of[c] = b
            stack.append(c)
    frames = read_amc(amc_path)
    f = len(frames)

    def local_motion(bone: str, values: np.ndarray) -> np.ndarray:
        ang = np.zeros((f, 3))
        for k, d in enumerate(bones[bone]["dof"]):
            if d in ("rx", "ry", "rz"):
                ang[:, "xyz".index(d[1])] = values[:, k]
        return Rotation.from_euler("xyz", ang, degrees=True).as_matrix()  # Rz Ry Rx

    def values(bone: str, n: int) -> np.ndarray:
        return np.array([fr.get(bone, [0.0] * n) for fr in frames], dtype=np.float64).reshape(f, n)

    names, parents, pos_l, rot_l, rest_pos_l, rest_rot_l = [], [], [], [], [], []
    end_pos: dict[str, tuple] = {}
    root = bones["root"]
    rv = values("root", len(root["order"]))
    r_ang = np.zeros((f, 3))
    r_pos = np.zeros((f, 3))
    for k, ch in enumerate(root["order"]):
        (r_pos if ch[0] == "T" else r_ang)[:, "XYZ".index(ch[1])] = rv[:, k]
    r_rot = Rotation.from_euler(root["root_axis"].lower(), r_ang, degrees=True).as_matrix()
    world_rot = {"root": r_rot}
    rest_world_rot = {"root": np.eye(3)}
    end_pos["root"] = (r_pos, np.zeros(3))
    for b in order:
        p = parent_of[b]
        bone = bones[b]
        if p is not None:
            c = bone["axis"]
            m = local_motion(b, values(b, len(bone["dof"])))
            world_rot[b] = world_rot[p] @ c @ m @ c.T
            rest_world_rot[b] = rest_world_rot[p]
        start, rest_start = end_pos[p] if p is not None else end_pos["root"]
        vec = bone["direction"] * bone["length"]
        end_pos[b] = (start + np.einsum("fij,j->fi", world_rot[b], vec), rest_start + vec)
        names.append(b)
        parents.append(-1 if p is None else names.index(p))
        pos_l.append(start)
        rot_l.append(world_rot[b])
        rest_pos_l.append(rest_start)
        rest_rot_l.append(rest_world_rot[b])
        if not hier.get(b) and p is not None:
            names.append(b + "_end")
            parents.append(names.index(b))
            pos_l.append(end_pos[b][0])
            rot_l.append(world_rot[b])
            rest_pos_l.append(end_pos[b][1])
            rest_rot_l.append(rest_world_rot[b])
    return SourceMotion(names, parents, np.stack(pos_l, 1), np.stack(rot_l, 1),
                        np.stack(rest_pos_l), np.stack(rest_rot_l), fps)
