"""What the per-frame pass of ``recon video`` gets wrong, frame to frame: the noise model the
motion prior (``recon.video.prior``) is trained with.

On the validation clips (synth-video-val and synth-video-moving-val: held-out mocap subjects the
prior never trains on), each frame's per-frame estimate (SMPLR's body on that frame, the track
optimisation's starting point) is matched to the true person by its projected joints, and its
error split into three parts per run of consecutive frames:

* the bias: the run's mean error of the root-relative J+ (what no smoothing removes);
* the wobble: what is left, per J+ and axis of the camera (x, y, z), as a first-order
  autoregressive process: its standard deviation and its correlation from one frame to the next;
* the root's error relative to its depth (x, y across the image, z along the line of sight), the
  same way;
* each joint's local rotation against the truth's (the per-frame body is always a body: its
  errors are in the joints' rotations, which is how the prior's training noise is drawn), and
  the track's body shape.

    OMP_NUM_THREADS=1 .venv/bin/python eval/motion_noise.py   # reads eval/video.py's stored detections

-> eval/results/motion-noise.{json,md}. The per-frame detections are those eval/video.py stored
(``<cache>/eval-video-work/<clip>/.work``); a clip without them is run first (``recon video``).
"""
from __future__ import annotations

import argparse

import numpy as np
import torch
import video as video_eval  # eval/video.py, beside this file
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

from recon import camera, metrics, report
from recon.body import default_body, skeleton
from recon.video import prior as motion_prior
from recon.video.perframe import Detections

BENCHES = ("synth-video-val", "synth-video-moving-val")
MIN_RUN = 10  # frames: shorter runs say little about the wobble's correlation


def residuals(body, dets: Detections, truth) -> list[dict]:
    """Per run of consecutive frames matched to one true person: the J+ error (T, 42, 3),
    root-relative, and the root's error over its depth (T, 3)."""
    with torch.no_grad():
        pts = body(torch.tensor(dets.rotmats), torch.tensor(dets.shape), transl=torch.tensor(dets.translation),
                   points_only=True).points.numpy().astype(np.float64)
    per_person: dict[int, dict[int, int]] = {}
    for n in range(len(dets)):
        f = int(dets.frame[n])
        best, best_d = None, 0.5
        for p in range(truth.points.shape[0]):
            if not truth.visible[p, f]:
                continue
            g2 = camera.project(truth.joints[p, f], truth.K)
            size = max(np.ptp(g2[:, 0]), np.ptp(g2[:, 1]), 1.0)
            d = np.median(np.linalg.norm(camera.project(pts[n, :24], truth.K) - g2, axis=1)) / size
            if d < best_d:
                best, best_d = p, d
        if best is not None:
            per_person.setdefault(best, {})[f] = n
    runs = []
    for p, frames in per_person.items():
        fs = sorted(frames)
        start = 0
        for i in range(1, len(fs) + 1):
            if i == len(fs) or fs[i] != fs[i - 1] + 1:
                run = fs[start:i]
                start = i
                if len(run) < MIN_RUN:
                    continue
                rows = [frames[f] for f in run]
                est = pts[rows]
                true = truth.points[p, run]
                rel = (est - est[:, :1]) - (true - true[:, :1])
                root = (est[:, 0] - true[:, 0]) / true[:, 0, 2:3]
                true_rot = Rotation.from_rotvec(truth.pose[p, run].reshape(-1, 3)).as_matrix().reshape(-1, 24, 3, 3)
                true_rot[:, 0] = truth.R[run] @ true_rot[:, 0]  # the root into each frame's camera
                off = np.swapaxes(true_rot, -1, -2) @ dets.rotmats[rows].astype(np.float64)
                turn = Rotation.from_matrix(off.reshape(-1, 3, 3)).as_rotvec().reshape(-1, 24, 3)
                shape = np.median(dets.shape[rows], 0) - truth.shape[p]
                runs.append({"rel": rel, "root": root, "turn": turn, "shape": shape, "est": est, "true": true})
    return runs


def smoothers(runs: list[dict]) -> dict:
    """The per-frame J+ of each run as they are, through the motion prior, and filtered in time
    (Gaussian): MPJPE and acceleration error of the root-relative J+ (frames weighted alike), and
    jitter against the truth's."""
    prior = motion_prior.load()
    ways = {"per frame": lambda x: x,
            "motion prior": lambda x: motion_prior.denoise(prior, x, np.ones(len(x), bool))[0]}
    for s in (1, 2, 3):
        ways[f"Gaussian, {s} frames"] = lambda x, s=s: gaussian_filter1d(x, s, axis=0, mode="nearest")
    rows = {}
    for name, way in ways.items():
        err, aerr, jit, jit_true = [], [], [], []
        for r in runs:
            out, true = torch.as_tensor(way(r["est"])), torch.as_tensor(r["true"])
            err.append(metrics.per_point_error(out, true).mean(1))
            aerr.append(metrics.acceleration_error(out, true) * (len(out) - 2))
            jit.append(metrics.jitter(out, None) * len(out))
            jit_true.append(metrics.jitter(true, None) * len(out))
        rows[name] = {"mpjpe": float(torch.cat(err).mean() * 1000),
                      "accel": float(sum(aerr) / sum(len(r["est"]) - 2 for r in runs) * 1000),
                      "jitter_ratio": float(sum(jit) / sum(jit_true))}
    return rows


def ar1(x: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Standard deviation and lag-1 correlation of zero-mean runs (T, ...), pooled."""
    var = sum((r ** 2).sum(0) for r in x) / sum(len(r) for r in x)
    cov = sum((r[1:] * r[:-1]).sum(0) for r in x) / sum(len(r) - 1 for r in x)
    return np.sqrt(var), np.clip(cov / np.maximum(var, 1e-12), -0.99, 0.99)


def measure(benches=BENCHES) -> dict:
    body = default_body()
    runs = []
    for bench in benches:
        for clip, path, truth in video_eval.clips(bench):
            runs += residuals(body, video_eval.stored_detections(clip, path, truth, body), truth)
    bias = np.stack([r["rel"].mean(0) for r in runs])  # (runs, 42, 3)
    wobble = [r["rel"] - r["rel"].mean(0) for r in runs]
    sigma, rho = ar1(wobble)
    root_bias = np.stack([r["root"].mean(0) for r in runs])
    root_sigma, root_rho = ar1([r["root"] - r["root"].mean(0) for r in runs])
    turn_bias = np.stack([r["turn"].mean(0) for r in runs])
    turn_sigma, turn_rho = ar1([r["turn"] - r["turn"].mean(0) for r in runs])
    shape = np.stack([r["shape"] for r in runs])
    # big single-frame errors beyond the AR model: share of frames where a point is off by > 4 sigma
    z = np.concatenate([np.linalg.norm(w / sigma, axis=-1) for w in wobble])
    return {
        "smoothers": smoothers(runs),
        "benches": list(benches), "runs": len(runs), "frames": int(sum(len(r["rel"]) for r in runs)),
        "points": list(skeleton.POINT_NAMES),
        "bias_sigma": np.sqrt((bias ** 2).mean(0)).round(5).tolist(),
        "sigma": sigma.round(5).tolist(), "rho": rho.round(4).tolist(),
        "root_bias_sigma": np.sqrt((root_bias ** 2).mean(0)).round(5).tolist(),
        "root_sigma": root_sigma.round(5).tolist(), "root_rho": root_rho.round(4).tolist(),
        "joints": list(skeleton.JOINT_NAMES),
        "turn_bias_sigma": np.sqrt((turn_bias ** 2).mean(0)).round(5).tolist(),
        "turn_sigma": turn_sigma.round(5).tolist(), "turn_rho": turn_rho.round(4).tolist(),
        "shape_sigma": np.sqrt((shape ** 2).mean(0)).round(4).tolist(),
        "outlier_share": float((z > 4 * np.sqrt(3)).mean().round(5)),
    }


def markdown(m: dict) -> str:
    lines = ["# The per-frame pass's noise on the validation clips", "",
             f"`eval/motion_noise.py` on {', '.join(m['benches'])}: {m['runs']} runs of at least {MIN_RUN} frames "
             f"matched to one true person, {m['frames']} frames. Root-relative J+ in the camera frame (mm); the "
             "root's error as a share of its depth (%). The wobble is an AR(1) process per point and axis "
             "(sigma, rho: correlation from one frame to the next); the bias is a run's mean error.", "",
             "| point | bias x / y / z | wobble sigma x / y / z | rho x / y / z |", "|---|---|---|---|"]
    for i, name in enumerate(m["points"]):
        b, s, r = (np.array(m[k][i]) for k in ("bias_sigma", "sigma", "rho"))
        lines.append(f"| {name} | {' / '.join(f'{v * 1000:.0f}' for v in b)} | "
                     f"{' / '.join(f'{v * 1000:.1f}' for v in s)} | {' / '.join(f'{v:.2f}' for v in r)} |")
    lines += ["", "Each joint's local rotation against the truth's (degrees, about the joint's own x / y / z axes; the "
              "root's in the camera frame):", "", "| joint | bias | wobble sigma | rho |", "|---|---|---|---|"]
    for i, name in enumerate(m["joints"]):
        b, s, r = (np.array(m[k][i]) for k in ("turn_bias_sigma", "turn_sigma", "turn_rho"))
        lines.append(f"| {name} | {' / '.join(f'{np.degrees(v):.1f}' for v in b)} | "
                     f"{' / '.join(f'{np.degrees(v):.1f}' for v in s)} | {' / '.join(f'{v:.2f}' for v in r)} |")
    lines += ["", f"The track's body shape (median over the run) against the truth's, per parameter: "
              f"{', '.join(f'{v:.3f}' for v in m['shape_sigma'])} (standard deviation)."]
    lines += ["", "The same runs' per-frame J+ through the motion prior (`recon.video.prior`, alone, without the track "
              "optimisation) and through a Gaussian filter in time (mm; acceleration error of the root-relative J+ in "
              "mm/frame^2; jitter of the J+ against the truth's):", "",
              "| J+ | MPJPE | accel error | jitter / truth's |", "|---|---|---|---|"]
    for name, r in m["smoothers"].items():
        lines.append(f"| {name} | {r['mpjpe']:.1f} | {r['accel']:.1f} | {r['jitter_ratio']:.2f} |")
    rb, rs, rr = (np.array(m[k]) for k in ("root_bias_sigma", "root_sigma", "root_rho"))
    lines += ["", f"Root / depth: bias {' / '.join(f'{v * 100:.2f}' for v in rb)} %, wobble sigma "
              f"{' / '.join(f'{v * 100:.2f}' for v in rs)} %, rho {' / '.join(f'{v:.2f}' for v in rr)}. "
              f"Frames with a point off by more than 4 sigma: {m['outlier_share'] * 100:.2f} %.", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bench", nargs="+", default=list(BENCHES))
    args = ap.parse_args()
    torch.set_num_threads(1)
    m = measure(tuple(args.bench))
    out = report.RESULTS / "motion-noise"
    report.write(out, m, markdown(m))
    print(markdown(m))


if __name__ == "__main__":
    main()
