"""``recon video`` on synthetic videos with ground truth (issue 53's benchmark).

    OMP_NUM_THREADS=1 .venv/bin/python eval/video.py --bench synth-video-test   # ~25 min on 1 core
    OMP_NUM_THREADS=1 .venv/bin/python eval/video.py --bench synth-video-moving-test

The clips of ``recon.synth.video.VIDEO_BENCHMARKS[bench]`` (held-out mocap subjects, 30 fps,
people entering and leaving, two people in some; a static camera, or in the ``-moving-`` sets a
panning, tilting, hand-held and walking one; in the ``-occlusion-`` sets look-alikes, one passing
behind the other) are rendered once into the cache. Rows:

* ``per-frame recon run``: every frame through ``recon run``'s reconstruction on its own (MediaPipe
  heavy with its mirror pass, retries and backbone, SMPLR, the per-image fit); no tracks;
* ``video mode, no smoothing``: ``recon video`` with ``SmoothConfig(steps=0)``: MediaPipe's video
  mode (several people: found one after the other), SMPLR per frame, tracks, gaps interpolated;
* ``recon video``: the same with the track optimisation;
* ``recon video --static-camera`` (moving sets): the camera's turn left in the people's motion;
* ``recon video --keypoint-model heavy|full`` (on request, ``--methods``): another landmark model;
* ``recon video``, 0.29's tracker (on request): boxes, keypoints and colours, no motion through gaps.

The cameras' true focal length is given to every row. Each frame's people are matched to the
truth by their projected joints (within half the person's box; a track matched the frame before
is kept while within it, as CLEAR MOT does, the rest by Hungarian assignment). Metrics over matched
frames (mm, root-aligned): MPJPE, PA-MPJPE, PVE; acceleration error (VIBE: mean distance between
predicted and true joint accelerations, mm/frame^2, triples of frames matched to one track);
jitter (mean jerk, mm/frame^3; the truth's own is listed); foot skating (cm a frame a foot joint
moves, world frame, where the truth has it planted: within 5 cm of its lowest height and moving
under 2 cm a frame); identity switches (a true person matched to another track than the frame
before); found (matched / visible person-frames); frames/s (the row's own time, no overlay).
World-grounded (recon.metrics, as WHAM and GVHMR report them; a track's world frame against the
scene's, the per-frame row's camera frame taken as its world): WA-MPJPE and W-MPJPE on chunks of
100 frames of a run matched to one track (aligned as a whole, or on its first two frames), RTE
(the root path rigidly aligned, in % of the distance the person walked; runs of at least 1 m),
the jitter of each row against the truth's on the same frames, and per true person their foot
skating and jitter ratio (the worst one counts). Jitter and foot skating are measured in these
world frames too (a turning camera's motion is not the person's).
Writes eval/results/<bench>.{json,md} (``--out``); rows of methods not run (``--methods``) are kept
from the file when it was made on the same clips.
"""
from __future__ import annotations

import argparse
import json
import time
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment
from tqdm import tqdm

from recon import camera, metrics, paths, report
from recon.body import default_body, skeleton
from recon.pipeline import Reconstructor
from recon.reconstruction import ReconstructorConfig
from recon.synth.video import SIZE, VIDEO_BENCHMARKS, VIDEO_GENERATOR, ClipRenderer, ClipTruth, write_clip
from recon.video import smooth
from recon.video.camera_motion import turned_degrees
from recon.video.frames import FrameSource
from recon.video.perframe import Detections
from recon.video.run import VideoOptions, camera_centres, video
from recon.video.track import TrackerConfig

METHODS = ("per-frame", "video-raw", "video", "video-static", "video-heavy", "video-full", "video-tracker-0.29")
LABELS = {"per-frame": "per-frame `recon run`", "video-raw": "video mode, no smoothing", "video": "`recon video`",
          "video-static": "`recon video --static-camera`", "video-heavy": "`recon video --keypoint-model heavy`",
          "video-full": "`recon video --keypoint-model full`",
          "video-tracker-0.29": "`recon video`, 0.29's tracker (no motion through gaps)"}
ON_REQUEST = ("video-heavy", "video-full", "video-tracker-0.29")  # run only when named
MODELS = ("video-heavy", "video-full")  # other landmark models
FEET = [skeleton.JOINT_NAMES.index(n) for n in ("left_foot", "right_foot")]


def clips(bench: str) -> list[tuple[str, Path, ClipTruth]]:
    """(name, video path, truth) of every clip, rendered into the cache when missing."""
    root = paths.cache_dir() / "synth" / f"{bench}-v{VIDEO_GENERATOR}"
    out, renderer = [], None
    for spec in VIDEO_BENCHMARKS[bench]:
        mp4, npz = root / f"{spec.name}.mp4", root / f"{spec.name}.npz"
        if not (mp4.exists() and npz.exists()):
            renderer = renderer or ClipRenderer(default_body())
            frames, truth = renderer.render(spec)
            write_clip(frames, mp4)
            truth.save(npz)
        out.append((spec.name, mp4, ClipTruth.load(npz)))
    return out


def predict_per_frame(path: Path, truth: ClipTruth, rec: Reconstructor) -> list[list[tuple]]:
    """Per frame [(track id None, joints (24, 3), vertices (V, 3), joints)], camera frame (also as
    the world frame: a single image has no other)."""
    out = []
    people = truth.joints.shape[0]
    for frame in FrameSource(path):
        res = rec.people([frame.rgb], [truth.K], people)[0]
        out.append([] if isinstance(res, Exception) else [(None, r.joints, r.vertices, r.joints) for r in res])
    return out


def predict_video(path: Path, truth: ClipTruth, smoothing: smooth.SmoothConfig, work: Path, body,
                  force: bool = True, static_camera: bool = False, keypoint_model: str | None = None,
                  tracker: TrackerConfig | None = None) -> tuple[list[list[tuple]], dict]:
    """``recon video``'s people per frame [(track id, joints, vertices in the frame's camera, joints
    in the track's world frame)], with the track optimisation ``smoothing``, and what video.json says
    of the camera; without ``force`` the per-frame detections stored in ``work`` are read back."""
    people = truth.joints.shape[0]
    cfg = ReconstructorConfig(focal_factor=float(truth.K[0, 0]) / max(SIZE))
    cfg = cfg if keypoint_model is None else replace(cfg, keypoint_model=keypoint_model)
    opts = VideoOptions(max_people=people, smooth=smoothing, overlay=False, force=force, static_camera=static_camera,
                        tracker=tracker or TrackerConfig())
    (work / "video.json").unlink(missing_ok=True)  # a finished folder would be left as it is, with no tracks
    res = video(path, work, opts, cfg, progress=False, log=lambda m: None)
    out: list[list[tuple]] = [[] for _ in range(len(res.frames.index))]
    summary = json.loads((work / "video.json").read_text())
    cam = {k: summary.get(k) for k in ("static_camera", "camera_turned_degrees", "camera_turn_measured",
                                       "camera_travelled")}
    for m in res.tracks:
        with torch.no_grad():
            o = body(torch.tensor(m.rotmats, dtype=torch.float32),
                     torch.tensor(m.shape[None], dtype=torch.float32),
                     transl=torch.tensor(m.translation, dtype=torch.float32))
        j, v = o.joints.numpy().astype(np.float64), o.vertices.numpy().astype(np.float64)
        for f in range(len(m.rotmats)):
            out[m.first + f].append((m.id, m.to_camera(j[f], f), m.to_camera(v[f], f), j[f]))
    return out, cam


def stored_detections(clip: str, path: Path, truth: ClipTruth, body) -> Detections:
    """The clip's stored per-frame detections (made with ``recon video``'s defaults when missing)."""
    work = paths.cache_dir() / "eval-video-work" / clip
    if not sorted((work / ".work").glob("batch-*.npz")):
        predict_video(path, truth, smooth.SmoothConfig(steps=0), work, body)
    parts = []
    for f in sorted((work / ".work").glob("batch-*.npz")):
        with np.load(f) as z:  # frames are numbered within their batch; the file holds the batch's source indices
            d = Detections(**{k.name: z[k.name] for k in fields(Detections)})
            d.frame = z["indices"][d.frame]
        parts.append(d)
    return Detections.concat(parts)


def true_turns(truth: ClipTruth) -> np.ndarray:
    """(F, 3, 3): each frame's true camera turned from the first one's (``x_t = R_t x_0``)."""
    return np.einsum("fij,kj->fik", truth.R, truth.R[0])


def true_turn(truth: ClipTruth) -> float:
    """The largest angle (degrees) between the clip's first camera and any later one's."""
    return turned_degrees(true_turns(truth))


def true_travel(truth: ClipTruth) -> float:
    """The farthest (m) the camera's centre got from where it started."""
    eye = camera_centres(truth.R, truth.t)
    return float(np.linalg.norm(eye - eye[0], axis=1).max())


def match(truth: ClipTruth, pred: list[list[tuple]]) -> np.ndarray:
    """(P, F) index into pred[f] of the prediction matched to true person p, -1 where none. As
    CLEAR MOT does: a person's track of the frame before stays matched while still within reach
    (where two people overlap a distance cannot tell them apart), the rest by Hungarian assignment."""
    p_n, f_n = truth.visible.shape
    out = np.full((p_n, f_n), -1)
    for f in range(f_n):
        gts = [p for p in range(p_n) if truth.visible[p, f]]
        if not gts or not pred[f]:
            continue
        cost = np.full((len(gts), len(pred[f])), 1e6)
        for a, p in enumerate(gts):
            g2 = camera.project(truth.joints[p, f], truth.K)
            size = max(np.ptp(g2[:, 0]), np.ptp(g2[:, 1]), 1.0)
            for b, (_, j, _, _) in enumerate(pred[f]):
                d = np.median(np.linalg.norm(camera.project(j, truth.K) - g2, axis=1)) / size
                if d < 0.5:
                    cost[a, b] = d
        for a, p in enumerate(gts):
            before = out[p, f - 1] if f else -1
            track = pred[f - 1][before][0] if before >= 0 else None
            kept = [b for b, q in enumerate(pred[f]) if track is not None and q[0] == track and cost[a, b] < 1e6]
            if kept:
                out[p, f] = kept[0]
                cost[a, :] = cost[:, kept[0]] = 1e6
        for a, b in zip(*linear_sum_assignment(cost), strict=True):
            if cost[a, b] < 1e6:
                out[gts[a], f] = b
    return out


def planted(truth: ClipTruth) -> np.ndarray:
    """(P, F, 2) the true foot joints planted (module doc)."""
    return metrics.planted_feet(torch.as_tensor(truth.joints_world[:, :, FEET])).numpy()


RTE_MIN_PATH = 1.0  # m: RTE is a share of the distance walked, undefined for people standing still


def score(truth: ClipTruth, pred: list[list[tuple]], sums: dict, clip: str = "") -> None:
    """Add one clip's errors to ``sums`` (lists of per-item values)."""
    m = match(truth, pred)
    plant = planted(truth)
    for f in range(m.shape[1]):  # people towards each other: pelvis to pelvis, in the camera and in the world
        both = [p for p in range(m.shape[0]) if m[p, f] >= 0]
        for i, p in enumerate(both):
            for q in both[i + 1:]:
                a, b = pred[f][m[p, f]], pred[f][m[q, f]]
                between = (a[1][0] - b[1][0]) - (truth.joints[p, f, 0] - truth.joints[q, f, 0])
                sums["between_camera"].append(float(np.linalg.norm(between)) * 1000)
                sums["between_world"].append(abs(float(np.linalg.norm(a[3][0] - b[3][0]) - np.linalg.norm(
                    truth.joints_world[p, f, 0] - truth.joints_world[q, f, 0]))) * 1000)
    for p in range(m.shape[0]):
        vis = truth.visible[p]
        sums["visible"] += int(vis.sum())
        idx = [f for f in range(m.shape[1]) if m[p, f] >= 0]
        sums["found"] += len(idx)
        ids = {f: pred[f][m[p, f]][0] for f in idx}
        prev = None
        for f in idx:
            if prev is not None and ids[f] != prev:
                sums["id_switches"] += 1
            prev = ids[f]
        if not idx:
            continue
        pj = torch.tensor(np.stack([pred[f][m[p, f]][1] for f in idx]))
        gj = torch.tensor(truth.joints[p, idx])
        pw = torch.tensor(np.stack([pred[f][m[p, f]][3] for f in idx]))  # world frames
        gw = torch.tensor(truth.joints_world[p, idx])
        pv = torch.tensor(np.stack([pred[f][m[p, f]][2] - pred[f][m[p, f]][1][:1] for f in idx]))
        gv = torch.tensor(truth.vertices[p, idx].astype(np.float64))
        sums["mpjpe"] += (metrics.per_point_error(pj, gj).mean(1) * 1000).tolist()
        aligned = metrics.procrustes_align(pj, gj)
        sums["pa_mpjpe"] += (metrics.per_point_error(aligned, gj, None).mean(1) * 1000).tolist()
        sums["pve"] += ((pv - gv).norm(dim=-1).mean(1) * 1000).tolist()
        # runs of consecutive frames matched to one track
        runs, start = [], 0
        for n in range(1, len(idx) + 1):
            if n == len(idx) or idx[n] != idx[n - 1] + 1 or ids[idx[n]] != ids[idx[n - 1]]:
                runs.append(idx[start:n])
                start = n
        person = {"clip": clip, "person": p, "skate": [], "skate_truth": [], "jitter": [], "jitter_truth": []}
        for run in runs:
            a, b = idx.index(run[0]), idx.index(run[-1]) + 1
            sums["wa_mpjpe"] += (metrics.wa_mpjpe(pw[a:b], gw[a:b]) * 1000).tolist()
            sums["w_mpjpe"] += (metrics.w_mpjpe(pw[a:b], gw[a:b]) * 1000).tolist()
            if len(run) >= 2 and float((gw[a + 1:b, 0] - gw[a:b - 1, 0]).norm(dim=-1).sum()) >= RTE_MIN_PATH:
                sums["rte"].append(float(metrics.root_trajectory_error(pw[a:b, 0], gw[a:b, 0])) * 100)
            if len(run) >= 3:
                err = (metrics.acceleration(pj[a:b] - pj[a:b, :1]) - metrics.acceleration(gj[a:b] - gj[a:b, :1]))
                sums["accel"] += (err.norm(dim=-1).mean(1) * 1000).tolist()
            if len(run) >= 4:
                for key, x in (("jitter", pw[a:b]), ("jitter_truth", gw[a:b])):
                    sums[key].append(float(metrics.jitter(x) * 1000))
                    person[key].append(sums[key][-1])
            if len(run) >= 2:
                both = plant[p, run[1:]] & plant[p, run[:-1]]
                step = (pw[a + 1:b][:, FEET] - pw[a:b - 1][:, FEET]).norm(dim=-1).numpy()
                true_step = np.linalg.norm(np.diff(truth.joints_world[p, run][:, FEET], axis=0), axis=-1)
                sums["skate"] += (step[both] * 100).tolist()
                sums["skate_truth"] += (true_step[both] * 100).tolist()
                person["skate"] += (step[both] * 100).tolist()
                person["skate_truth"] += (true_step[both] * 100).tolist()
        sums["people"].append({k: (float(np.mean(v)) if v else None) if isinstance(v, list) else v
                               for k, v in person.items()})


def new_sums() -> dict:
    """Empty per-item lists and counters for ``score``."""
    sums = {k: [] for k in ("mpjpe", "pa_mpjpe", "pve", "accel", "jitter", "jitter_truth", "skate", "skate_truth",
                            "wa_mpjpe", "w_mpjpe", "rte", "people", "between_camera", "between_world")}
    return sums | {"visible": 0, "found": 0, "id_switches": 0}


def summarise(sums: dict, seconds: float, frames: int) -> dict:
    mean = lambda k: float(np.mean(sums[k])) if sums[k] else None  # noqa: E731
    people = [q for q in sums["people"] if q["skate"] is not None or q["jitter"] is not None]
    skates = [q["skate"] for q in people if q["skate"] is not None]
    ratios = [q["jitter"] / q["jitter_truth"] for q in people if q["jitter"] is not None and q["jitter_truth"]]
    world = {"wa_mpjpe": mean("wa_mpjpe"), "w_mpjpe": mean("w_mpjpe"), "rte_pct": mean("rte"),
             "rte_runs": len(sums["rte"]),
             "jitter_ratio": mean("jitter") / mean("jitter_truth") if sums["jitter"] else None,
             "worst_person_skating_cm": max(skates) if skates else None,
             "people_skating_over_2cm": sum(x >= 2.0 for x in skates),
             "person_jitter_ratio_range": [min(ratios), max(ratios)] if ratios else None, "people": people,
             "between_camera": mean("between_camera"), "between_world": mean("between_world")}
    return world | {"mpjpe": mean("mpjpe"), "pa_mpjpe": mean("pa_mpjpe"), "pve": mean("pve"), "accel": mean("accel"),
            "jitter": mean("jitter"), "jitter_truth": mean("jitter_truth"), "foot_skating_cm": mean("skate"),
            "foot_skating_truth_cm": mean("skate_truth"), "id_switches": sums["id_switches"],
            "found": sums["found"] / max(sums["visible"], 1), "person_frames": sums["visible"],
            "frames_per_second": frames / seconds}


def markdown(bench: str, rows: dict, data: dict, machine: dict) -> str:
    head = ["method", "MPJPE", "PA-MPJPE", "PVE", "accel error", "jitter", "foot skating (cm)", "ID switches",
            "found", "frames/s"]
    body = [[LABELS[k], r["mpjpe"], r["pa_mpjpe"], r["pve"], r["accel"], r["jitter"], r["foot_skating_cm"],
             None if k == "per-frame" else r["id_switches"], f"{100 * r['found']:.1f} %", r["frames_per_second"]]
            for k, r in rows.items()]
    any_row = rows.get("video") or next(iter(rows.values()))
    body.append(["ground truth (on the last row's frames)", None, None, None, None, any_row["jitter_truth"],
                 any_row["foot_skating_truth_cm"], None, None, None])
    world_head = ["method", "WA-MPJPE", "W-MPJPE", "RTE %", "RTE runs", "jitter / truth's",
                  "jitter ratio per person", "worst person's skating (cm)", "people skating >= 2 cm",
                  "between people: camera", "world"]
    spread = lambda r: "{:.2f}-{:.2f}".format(*r["person_jitter_ratio_range"]) if r.get(  # noqa: E731
        "person_jitter_ratio_range") else None
    world = [[LABELS[k], r.get("wa_mpjpe"), r.get("w_mpjpe"), r.get("rte_pct"), r.get("rte_runs"),
              r.get("jitter_ratio"), spread(r), r.get("worst_person_skating_cm"), r.get("people_skating_over_2cm"),
              r.get("between_camera"), r.get("between_world")] for k, r in rows.items()]
    return "\n".join([
        f"# `recon video` on {bench}", "",
        f"{data['clips']} clips, {data['frames']} frames of 640 x 480 at 30 fps, {any_row['person_frames']} visible "
        "person-frames (eval/video.py; clips: recon/synth/video.py). mm unless stated; acceleration error in "
        "mm/frame^2, jitter in mm/frame^3; ID switches are not defined without tracks.", "",
        report.table(body, head, [".1f"] * 9 + [".1f"]), "",
        "Rows score the frames where they have the person: `recon video` also its bridged gaps.", "",
        "World-grounded (each track's world frame against the scene's; the per-frame row has only the camera's; "
        f"chunks of 100 frames; RTE on runs of at least {RTE_MIN_PATH:g} m walked):", "",
        report.table(world, world_head, ["", ".1f", ".1f", ".1f", "", ".2f", "", ".1f", "", ".0f", ".0f"]), "",
        "Between people (clips of several): the error of one person's pelvis seen from another's, in the camera "
        "(mm), and of the distance between them in the world frames (mm; the files of one clip share one "
        "world since 0.31).", "",
        *camera_table(rows.get("video", {}).get("cameras")),
        f"Machine: {report.describe(machine)}.", ""])


def camera_table(cameras: dict | None) -> list[str]:
    """The camera's turn per clip as `recon video` measured it (video.json) against the truth."""
    if not cameras:
        return []
    body = [[name, c["true_turn_degrees"], c["camera_turned_degrees"], f"{100 * c['camera_turn_measured']:.0f} %",
             "still" if c["static_camera"] else "taken out", c.get("true_travel_m"),
             {True: "yes", False: "no", None: "-"}[c.get("camera_travelled")]] for name, c in cameras.items()]
    head = ["clip", "true turn (deg)", "measured turn (deg)", "frames measured", "recon video", "true move (m)",
            "move detected"]
    return ["The camera's turn per clip (`recon video`; no measured turn: too little of the turn measured, taken "
            "as still), and whether it moved:", "", report.table(body, head, ["", ".2f", ".2f", "", "", ".2f", ""]), ""]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bench", default="synth-video-test", choices=tuple(VIDEO_BENCHMARKS))
    ap.add_argument("--methods", default=None, help=f"of {METHODS} (default: all; video-static on moving sets)")
    ap.add_argument("--clips", type=int, default=None, help="only the first clips")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)
    data = clips(args.bench)[:args.clips]
    body = default_body()
    work = paths.cache_dir() / "eval-video-work"
    rows = {}
    methods = args.methods.split(",") if args.methods else [
        m for m in METHODS if ("moving" in args.bench or m != "video-static") and m not in ON_REQUEST]
    for method in methods:
        sums, cameras = new_sums(), {}
        seconds, frames = 0.0, 0
        rec = None
        for name, path, truth in tqdm(data, desc=method):
            t0 = time.perf_counter()
            if method == "per-frame":
                cfg = ReconstructorConfig(focal_factor=float(truth.K[0, 0]) / max(SIZE))
                rec = rec or Reconstructor(cfg, body=body)
                pred = predict_per_frame(path, truth, rec)
            else:
                steps = 0 if method == "video-raw" else smooth.SmoothConfig.steps
                model = method.removeprefix("video-") if method in MODELS else None
                pred, cam = predict_video(path, truth, smooth.SmoothConfig(steps=steps), work / (name + (model or "")),
                                          body, force=method != "video-static", static_camera=method == "video-static",
                                          keypoint_model=model,
                                          tracker=TrackerConfig(motion=False) if method == "video-tracker-0.29"
                                          else None)
                cameras[name] = cam | {"true_turn_degrees": true_turn(truth), "true_travel_m": true_travel(truth)}
            seconds += time.perf_counter() - t0
            frames += truth.visible.shape[1]
            score(truth, pred, sums, name)
        rows[method] = summarise(sums, seconds, frames) | ({"cameras": cameras} if cameras else {})
        print(method, {k: (round(v, 2) if isinstance(v, float) else v) for k, v in rows[method].items()})
    info = {"clips": len(data), "frames": int(sum(t.visible.shape[1] for _, _, t in data))}
    out = Path(args.out) if args.out else report.RESULTS / args.bench
    if out.with_suffix(".json").exists():  # the rows not run now stay, when made on the same clips
        old = report.read(out)
        if old.get("bench") == args.bench and all(old.get(k) == v for k, v in info.items()):
            rows = {k: old["rows"][k] for k in METHODS if k in old["rows"] and k not in rows} | rows
    rows = {k: rows[k] for k in METHODS if k in rows}
    machine = report.machine()
    report.write(out, {"bench": args.bench, **info, "rows": rows, "machine": machine},
                 markdown(args.bench, rows, info, machine))


if __name__ == "__main__":
    main()
