"""Load a user-supplied SMPL-family model file (.npz or .pkl). recon ships no such file.

Expected arrays (SMPL naming): v_template (V,3), shapedirs (V,3,S), posedirs (V,3,207) or
(V*3,207), J_regressor (24,V) dense or scipy-sparse, weights (V,24), kintree_table (2,24)
and f (F,3). The model must use SMPL's 24-joint order (recon.body.skeleton) and SMPL's
frame (+Y up, +Z forward, metres), which is recon's body frame. Pickles written with chumpy
are read without chumpy; only numpy/scipy/chumpy classes are allowed while unpickling.
"""
from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import torch

from recon.body import skeleton
from recon.body.base import BodyModel
from recon.errors import MissingFile, ReconError

REQUIRED = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f")


class RefusedPickle(ReconError, pickle.UnpicklingError):
    """A .pkl model file asks to build an object that is not numpy/scipy data."""


class _ChumpyArray:
    """Stands in for chumpy.Ch while unpickling: keeps the wrapped array ``x``."""

    def __init__(self, *args, **kwargs):
        self.state = {}

    def __setstate__(self, state):
        self.state = state if isinstance(state, dict) else {"x": state}

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self.state.get("x"), dtype=dtype)


class _SafeUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        if module.startswith("chumpy"):
            return _ChumpyArray
        if module.split(".")[0] in ("numpy", "scipy") or (module, name) in (
            ("builtins", "object"), ("copy_reg", "_reconstructor"), ("copyreg", "_reconstructor"),
            ("__builtin__", "object"), ("_codecs", "encode"),
        ):
            return super().find_class(module, name)
        raise RefusedPickle(f"refusing to load {module}.{name} from a model file")


def _dense(a) -> np.ndarray:
    if hasattr(a, "toarray"):
        a = a.toarray()
    return np.asarray(a, dtype=np.float64)


def load_model_arrays(path: str | Path) -> dict[str, np.ndarray]:
    path = Path(path)
    if not path.exists():
        raise MissingFile(f"body model file {path} does not exist")
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    elif path.suffix == ".pkl":
        with open(path, "rb") as fh:
            data = _SafeUnpickler(fh, encoding="latin1").load()
    else:
        raise ReconError(f"unsupported body model file type {path.suffix!r} (use .npz or .pkl)")
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise ReconError(f"{path.name} lacks {missing}; an SMPL-family file needs {list(REQUIRED)}")
    return {k: _dense(data[k]) for k in REQUIRED}


class SMPLFileBody(BodyModel):
    """SMPL-style model from arrays: shape blend shapes, joint regressor, pose correctives."""

    def __init__(self, path: str | Path, num_shape_params: int | None = None) -> None:
        super().__init__()
        d = load_model_arrays(path)
        v = d["v_template"]
        nv = v.shape[0]
        parents = tuple(int(p) for p in d["kintree_table"][0])
        parents = (-1,) + parents[1:]
        if len(parents) != skeleton.NUM_JOINTS or parents != skeleton.JOINT_PARENTS:
            raise ReconError(
                f"{Path(path).name}: kinematic tree {parents} is not SMPL's 24-joint tree "
                f"{skeleton.JOINT_PARENTS}"
            )
        shapedirs = d["shapedirs"].reshape(nv, 3, -1)
        if num_shape_params is not None:
            shapedirs = shapedirs[..., :num_shape_params]
        posedirs = d["posedirs"].reshape(nv * 3, -1)
        if posedirs.shape[1] != 9 * (skeleton.NUM_JOINTS - 1):
            raise ReconError(f"posedirs must have {9 * (skeleton.NUM_JOINTS - 1)} columns, got {posedirs.shape[1]}")
        f32 = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
        self.shape_names = tuple(f"beta{i}" for i in range(shapedirs.shape[-1]))
        self.register_buffer("v_template", f32(v), persistent=False)
        self.register_buffer("shapedirs", f32(shapedirs), persistent=False)
        self.register_buffer("posedirs", f32(posedirs.T), persistent=False)  # (207, V*3)
        self.register_buffer("J_regressor", f32(d["J_regressor"]), persistent=False)
        self.register_buffer("weights", f32(d["weights"]), persistent=False)
        self.register_buffer("faces", torch.as_tensor(d["f"].astype(np.int64)), persistent=False)
        self.register_buffer("mean_shape", torch.zeros(shapedirs.shape[-1]), persistent=False)
        self._finish_init()

    def rest_geometry(self, shape: torch.Tensor, vertex_ids: torch.Tensor | None = None
                      ) -> tuple[torch.Tensor, torch.Tensor]:
        verts = self.v_template + torch.einsum("bs,vks->bvk", shape, self.shapedirs)
        joints = torch.einsum("jv,bvk->bjk", self.J_regressor, verts)
        return (verts if vertex_ids is None else verts[:, vertex_ids]), joints

    def pose_offsets(self, rotmats: torch.Tensor, vertex_ids: torch.Tensor | None = None) -> torch.Tensor:
        eye = torch.eye(3, dtype=rotmats.dtype, device=rotmats.device)
        feat = (rotmats[:, 1:] - eye).reshape(rotmats.shape[0], -1)
        offsets = (feat @ self.posedirs).view(rotmats.shape[0], -1, 3)
        return offsets if vertex_ids is None else offsets[:, vertex_ids]
