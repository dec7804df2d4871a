"""Choose the track optimisation's weights (``recon.video.smooth.SmoothConfig``) on synth-video-val:
each clip's per-frame detections are computed once (kept in the cache), then every candidate
configuration smooths the tracks and is scored as eval/video.py scores ``recon video`` (MPJPE,
acceleration error, jitter against the truth's, foot skating of the worst person).

    OMP_NUM_THREADS=1 .venv/bin/python eval/smooth_tuning.py [--bench synth-video-val]

-> eval/results/smooth-tuning-<bench>.{json,md} (``--only``: those rows made again, the rest kept)
"""
from __future__ import annotations

import argparse
import json
from dataclasses import asdict, replace
from pathlib import Path

import torch
import video as video_eval  # eval/video.py, beside this file

from recon import paths, report
from recon.body import default_body
from recon.video import prior as motion_prior
from recon.video import smooth

# candidates: name -> changes to SmoothConfig's defaults
CANDIDATES = {
    "default": {},
    "feet planted from the 2D keypoints alone (0.28's default)": {"contact_from": "image"},
    "feet planted from the motion prior alone": {"contact_from": "prior"},
    "feet planted where the prior is 70 % sure (or the image)": {"planted_probability": 0.7},
    "feet planted where the prior is 85 % sure (or the image)": {"planted_probability": 0.85},
    "120 steps (the default to 0.14)": {"steps": 120},
    "120 steps, acceleration 30": {"steps": 120, "acceleration": 30.0},
    "120 steps, acceleration 10": {"steps": 120, "acceleration": 10.0},
    "250 steps": {"steps": 250},
    "toward the prior's J+, 1": {"prior": 1.0},
    "toward the prior's J+, 1, acceleration 10": {"prior": 1.0, "acceleration": 10.0},
    "toward the prior's J+, 3, its root 1, acceleration 10": {"prior": 3.0, "prior_root": 1.0, "acceleration": 10.0},
    "toward Gaussian-filtered J+ (2 frames), 1, acceleration 10": {"prior": 1.0, "acceleration": 10.0,
                                                                   "prior_kind": "gaussian"},
    "acceleration about the prior's": {"acceleration_about": "target"},
    "acceleration about Gaussian-filtered J+ (2 frames)": {"acceleration_about": "target", "prior_kind": "gaussian"},
    "acceleration about Gaussian-filtered J+ (3 frames)": {"acceleration_about": "target", "prior_kind": "gaussian",
                                                           "gaussian_sigma": 3.0},
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bench", default="synth-video-val")
    ap.add_argument("--only", nargs="*", default=None, help="candidate names (the file's other rows are kept)")
    ap.add_argument("--prior", default=None, help="motion prior weights (default: the shipped ones)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    if args.prior:
        motion_prior.WEIGHTS = Path(args.prior)
    body, data = default_body(), video_eval.clips(args.bench)
    out = report.RESULTS / f"smooth-tuning-{args.bench}"
    old = report.read(out) if out.with_suffix(".json").exists() else {}
    rows = {k: v for k, v in old.get("rows", {}).items() if k in CANDIDATES} if args.only else {}
    for name, change in CANDIDATES.items():
        if args.only and name not in args.only:
            continue
        cfg = replace(smooth.SmoothConfig(), **change)
        sums = video_eval.new_sums()
        for clip, path, truth in data:
            work = paths.cache_dir() / "eval-smooth-tuning" / args.bench / clip
            (work / "video.json").unlink(missing_ok=True)  # tracks made again; the detections stay
            video_eval.score(truth, video_eval.predict_video(path, truth, cfg, work, body, force=False)[0], sums, clip)
        r = video_eval.summarise(sums, 1.0, 1)
        rows[name] = {"config": asdict(cfg)} | {k: v for k, v in r.items() if k not in ("people", "frames_per_second")}
        print(name, json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in rows[name].items()
                                if k != "config"}), flush=True)
    rows = {k: rows[k] for k in CANDIDATES if k in rows}
    head = ["candidate", "MPJPE", "PA-MPJPE", "accel error", "jitter / truth's", "jitter ratio per person",
            "worst person's skating (cm)", "people skating >= 2 cm", "WA-MPJPE", "W-MPJPE", "RTE %"]
    body_rows = [[k, r["mpjpe"], r["pa_mpjpe"], r["accel"], r["jitter_ratio"],
                  "{:.2f}-{:.2f}".format(*r["person_jitter_ratio_range"]) if r["person_jitter_ratio_range"] else None,
                  r["worst_person_skating_cm"], r["people_skating_over_2cm"], r["wa_mpjpe"], r["w_mpjpe"],
                  r["rte_pct"]] for k, r in rows.items()]
    md = "\n".join([f"# The track optimisation's weights on {args.bench}", "",
                    "`eval/smooth_tuning.py`: the same per-frame detections, each candidate's track optimisation "
                    "(`SmoothConfig`), scored as eval/video.py scores `recon video` (mm; accel error mm/frame^2). "
                    "The default plants a foot where the 2D keypoints or the motion prior (`recon.video.prior`) say "
                    "so; \"toward\" rows also pull the body toward the prior's J+ (or the per-frame J+ filtered in "
                    "time) with that weight; \"acceleration about\" rows damp only the acceleration that departs "
                    "from theirs.", "",
                    report.table(body_rows, head, ["", ".1f", ".1f", ".1f", ".2f", "", ".1f", "", ".1f", ".1f",
                                                   ".1f"]), ""])
    print(Path(report.write(out, {"bench": args.bench, "rows": rows}, md)).read_text())


if __name__ == "__main__":
    main()
