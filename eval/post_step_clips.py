"""The garment post-step (strain step + collision resolution) on PBNS and NCS over the held-out clips.

    .venv/bin/python eval/post_step_clips.py [--outfit all]            (from the repository root)

The frames ``recon garment eval --model ncs`` scores (every 4th frame of every test-split clip,
the models run on every frame at 30 fps), for each preset: skinning, PBNS and NCS, each network
with and without the post-step the Dresser applies by default; collision %, edge error (mm, and
per bin of the body's own self-intersection), bending. The post-step's settings were chosen on
DeePSD's val outfits (garment-post-step-val.md). Writes eval/results/garment-post-step-clips.{json,md}.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from recon import report
from recon.body import default_body
from recon.garment.metrics import SELF_INTERSECTION_BINS
from recon.garment.ncs.eval import STRIDE, clip_rows, load_models, post_step, post_step_check, split_clips
from recon.garment.templates import PRESETS

CHECK_OUTFIT = "top-shorts"
# a vertex at the body's surface may count in or out on another CPU: collision % in hundredths
CHECK_TOLERANCE = {"rtol": 1e-3, "atol": 0.01}


def evaluate(outfits: list[str], log=print) -> dict:
    torch.set_num_threads(1)
    body = default_body()
    out = {"stride": STRIDE, "outfits": {}}
    for o in outfits:
        t0 = time.perf_counter()
        pbns, ncs, _, shape = load_models(o)
        out["outfits"][o] = clip_rows(body, pbns, ncs, shape, split_clips("test"), post=post_step(o, pbns))
        log(f"{o}: {time.perf_counter() - t0:.0f} s")
    return out


def render(data: dict) -> str:
    rows = []
    for o, r in data["outfits"].items():
        for m, x in r.items():
            bins = x.get("by_body_self_intersection", {})
            rows.append([o, m, x["collision_pct"], x["edge_mm"], x["bend"]]
                        + [f"{b['collision_pct']:.2f} / {b['edge_mm']:.2f}" if b["poses"] else "-"
                           for b in bins.values()])
    return "\n".join([
        "# Garment post-step on PBNS and NCS over the held-out clips", "",
        f"`eval/post_step_clips.py`: every {data['stride']}th frame of every test-split clip (performers 3, 9, 12, "
        "14), the models run on every frame at 30 fps (the frames of garment-ncs.md); \"+ post-step\": the "
        "Dresser's default after the network (recon.garment.collide: the strain step, then collision resolution; "
        "settings chosen on DeePSD's val outfits, garment-post-step-val.md). Thesis PBNS: collision 0.45 %, edge "
        "0.66 mm (on poses without body self-collisions). Last columns: collision % / edge mm per bin of the % of "
        "covered skin inside the body itself (recon.garment.self_intersection).", "",
        report.table(rows, ["outfit", "model", "collision %", "edge mm", "bend"]
                     + [f"body {lo:g}-{hi:g} %" for lo, hi in SELF_INTERSECTION_BINS],
                     ["", "", ".2f", ".2f", ".4f", "", "", ""])])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--outfit", nargs="+", default=["all"])
    ap.add_argument("--update", action="store_true", help="keep the other outfits' rows of the existing table")
    args = ap.parse_args()
    outfits = list(PRESETS) if args.outfit == ["all"] else args.outfit
    data = evaluate(outfits)
    stem = Path(report.RESULTS) / "garment-post-step-clips"
    if args.update and stem.with_suffix(".json").exists():  # another run's outfits stay, in preset order
        old = json.loads(stem.with_suffix(".json").read_text())["outfits"]
        merged = old | data["outfits"]
        data["outfits"] = {o: merged[o] for o in [*PRESETS, *merged] if o in merged}
    data["check"] = {"function": "recon.garment.ncs.eval:post_step_check", "kwargs": {"outfit": CHECK_OUTFIT},
                     "tolerance": CHECK_TOLERANCE, "values": post_step_check(CHECK_OUTFIT)}
    print(report.write(stem, data, render(data)))


if __name__ == "__main__":
    main()
