"""Body models behind one interface (see base.BodyModel and skeleton for conventions).

>>> import recon.body
>>> body = recon.body.create()             # anny 0.6.2, float32 (default)
>>> body = recon.body.create("my_smpl.npz")  # a user's SMPL-family file
"""
from __future__ import annotations

from pathlib import Path

from recon.body.anny_model import AnnyBody
from recon.body.base import BodyModel, BodyOutput
from recon.body.skeleton import JOINT_NAMES, JOINT_PARENTS, KINTREE_PLUS, LANDMARK_NAMES
from recon.body.smpl_file import SMPLFileBody
from recon.errors import ReconError

_CACHE: dict[str, BodyModel] = {}


def create(model: str | Path = "anny", **kwargs) -> BodyModel:
    """Body model factory: "anny" (default) or the path of an SMPL-family .npz/.pkl file."""
    if str(model) == "anny":
        return AnnyBody(**kwargs)
    if Path(model).suffix in (".npz", ".pkl"):
        return SMPLFileBody(model, **kwargs)
    raise ReconError(f"unknown body model {model!r}: use 'anny' or a path to an SMPL-family .npz/.pkl")


def default_body() -> BodyModel:
    """A process-wide shared anny instance (loading it takes a while)."""
    if "anny" not in _CACHE:
        _CACHE["anny"] = create("anny")
    return _CACHE["anny"]


__all__ = ["BodyModel", "BodyOutput", "create", "default_body", "JOINT_NAMES", "JOINT_PARENTS",
           "LANDMARK_NAMES", "KINTREE_PLUS"]
