"""``recon body`` and ``recon poses``: the body model and the retargeted pose set."""
from __future__ import annotations

from pathlib import Path

from recon.cli.parsing import COUNT, Parser, actions


def add_body(p: Parser) -> None:
    action = actions(p)
    a = action("build-cache", "body:body_build_cache", "build the anny float32 export once (~1-3 min)")
    a.add_argument("--force", action="store_true", help="rebuild even if it exists")
    a = action("info", "body:body_info", "print the body model's facts as JSON")
    a.add_argument("--model", default="anny", help="'anny' or an SMPL-family .npz/.pkl")
    a = action("export", "body:body_export", "write the rest body (mean shape) to model your own garments on")
    a.add_argument("--out", required=True, help="mesh file (.obj, .ply, .glb)")
    a.add_argument("--model", default="anny", help="'anny' or an SMPL-family .npz/.pkl")


def add_poses(p: Parser) -> None:
    action = actions(p)
    a = action("build", "body:poses_build", "retarget the raw clips ($RECON_SHARED_DIR/data/mocap) into a pose set")
    a.add_argument("--mocap", type=Path, default=None, help="folder of the raw clips (with metadata/clips.csv)")
    a.add_argument("--out", default=None, help="default: the recon cache")
    a.add_argument("--force", action="store_true", help="rebuild even if the output exists")
    a.add_argument("--limit", type=COUNT, default=None, help="only the first N clips (quick checks)")
    action("stats", "body:poses_stats", "split statistics of the pose set in use")


ADD = {"body": add_body, "poses": add_poses}

