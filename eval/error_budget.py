"""The image -> body error budget on synth-val (issue 27 step 1): where the millimetres go.

    OMP_NUM_THREADS=1 .venv/bin/python eval/collect_sources.py --source mediapipe --n 2000
    OMP_NUM_THREADS=1 .venv/bin/python eval/collect_sources.py --source backbone --n 500
    OMP_NUM_THREADS=1 .venv/bin/python eval/collect_sources.py --source backbone-gtcrop --n 500
    OMP_NUM_THREADS=1 .venv/bin/python eval/error_budget.py

Reads the sources' cached outputs (eval/collect_sources.py) and writes
eval/results/error-budget.{json,md}:

1. 2D error of each keypoint source: pixels and % of the person's box height, per joint group;
2. lifting: the same GT or detected 2D lifted by each lifting stage (the DAE-2D of SMPLR on
   metric orthographic points, the camera-aware lifter), then SMPLR; MPJPE P1 / PA and the
   error of the pelvis depth (the body placed by reprojection, or the lifter's own depth);
3. why MediaPipe misses: found rate by view, person size, truncation and occlusion.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import skimage.data
import torch
from scipy.spatial.transform import Rotation

from recon import camera, paths, report
from recon.body import default_body, skeleton
from recon.keypoints.sources import MediaPipeSource
from recon.metrics import per_point_error, procrustes_align
from recon.smplr import SMPLR
from recon.smplr.lifter import WEIGHTS as LIFTER_WEIGHTS
from recon.smplr.lifter import Lifter
from recon.smplr.lifter_train import box_height
from recon.synth.dataset import SynthDataset, bench_dir

GROUPS = {a: [skeleton.JOINT_NAMES.index(n) for n in names]
          for a, names in zip(("Hd", "Ts", "Sr", "Ew", "Wt", "Hp", "Kn", "Ft"), skeleton.JOINT_GROUPS.values(),
                              strict=True)}
GROUPS["Lm"] = list(range(24, 42))


def load(name: str) -> dict | None:
    p = paths.cache_dir() / "error-budget" / name
    return dict(np.load(p)) if p.exists() else None


def source_rows(files: dict[str, tuple[dict, int]]) -> list[list]:
    rows = []
    for name, (z, size) in files.items():
        f = z["found"]
        gt, pred = z["gt_points2d"][f], z["points2d"][f]
        err = np.linalg.norm(pred - gt, axis=-1)
        rel = 100 * err / box_height(gt)[:, None]
        inside = (gt >= 0).all(-1) & (gt < size).all(-1)
        rows.append([name, len(f), 100 * f.mean(), err.mean(), np.median(err), rel.mean(), rel[inside].mean(),
                     rel[~inside].mean() if (~inside).any() else None,
                     *(rel[:, idx].mean() for idx in GROUPS.values())])
    return rows


def mpjpe(pred: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p, g = torch.tensor(pred[:, :24], dtype=torch.float64), torch.tensor(gt[:, :24], dtype=torch.float64)
    p1 = per_point_error(p, g).mean(1).numpy() * 1000
    p2 = per_point_error(procrustes_align(p, g), g, None).mean(1).numpy() * 1000
    return p1, p2


def lift_rows(smplr: SMPLR, lifter: Lifter | None, routes: dict[str, tuple]) -> list:
    """routes: name -> (2D (N, 42, 2), source 3D (N, 42, 3) or None, K (N, 3, 3), GT J+ (N, 42, 3),
    image side)."""
    rows = []
    template = smplr.template.numpy()
    for name, (uv, p3, k, g, size) in routes.items():
        idx = np.arange(len(uv))
        vis = np.stack([camera.inside_image(u, (size, size)) for u in uv])
        weights = np.where(vis, 1.0, 0.1)
        variants = {}
        if p3 is None:  # 2D-only: the DAE-2D route of the old oracle and the camera-aware lifter
            xs = []
            for n in range(len(uv)):
                d = camera.depth_from_bones(uv[n], k[n], template)
                xs.append(np.concatenate([camera.normalized(uv[n], k[n]) * d, np.zeros((42, 1))], 1))
            variants["DAE-2D -> SMPLR"] = (np.stack(xs), "2d", True, None)
        else:
            variants["source 3D -> DAE -> SMPLR"] = (p3, "3d", True, None)
        if lifter is not None:
            lp, root = [], []
            for a in range(0, len(uv), 512):
                o = lifter.lift(uv[a:a + 512], k[a:a + 512], vis[a:a + 512])
                lp.append(o[0])
                root.append(o[1])
            lp, root = np.concatenate(lp), np.concatenate(root)
            if p3 is None:
                variants["lifter (J+ alone)"] = (lp, None, None, root)
                variants["lifter -> SMPLR"] = (lp, "3d", False, root)
                variants["lifter -> DAE -> SMPLR"] = (lp, "3d", True, root)
            else:  # the lifter alone is the 2D route's row
                variants["mean(lifter, source 3D) -> SMPLR"] = (0.5 * (lp + p3), "3d", False, root)
                variants["mean(lifter, source 3D) -> DAE -> SMPLR"] = (0.5 * (lp + p3), "3d", True, root)
        for vname, (pts, mode, denoise, root) in variants.items():
            if mode is None:
                pred = pts + root[:, None]
                z_place = root[:, 2]
            else:
                pred = np.concatenate([np.concatenate([b.joints, b.landmarks], 1) for a in range(0, len(pts), 256)
                                       for b in [smplr.lift_and_place(pts[a:a + 256], uv[a:a + 256], k[a:a + 256],
                                                                      weights[a:a + 256], mode=mode, denoise=denoise,
                                                                      points_only=True)]])
                z_place = pred[:, 0, 2]
            p1, p2 = mpjpe(pred, g)
            dz = np.abs(z_place - g[:, 0, 2])
            dz_lift = np.abs(root[:, 2] - g[:, 0, 2]) if root is not None else None
            rows.append([name, vname, len(idx), p1.mean(), p2.mean(), 1000 * np.median(dz), 1000 * dz.mean(),
                         None if dz_lift is None else 1000 * np.median(dz_lift)])
    return rows


def miss_rows(z: dict, ds: SynthDataset) -> list[list]:
    """MediaPipe's found rate by the image's attributes."""
    att = []
    for i in range(len(z["found"])):
        s = ds[i]
        front = s["R"] @ Rotation.from_rotvec(s["pose"][0]).as_matrix() @ np.array([0.0, 0.0, 1.0])
        uv = s["points2d"]
        att.append((-front[2], box_height(uv) * 256 / s["rgb"].shape[0], camera.inside_image(uv, s["rgb"].shape).mean(),
                    1 - s["mask"].sum() / max(s["silhouette"].sum(), 1)))
    facing, h, inside, occ = np.array(att).T
    f = z["found"]
    bins = {
        "view: front (facing within 60 deg)": facing > 0.5, "view: side": np.abs(facing) <= 0.5,
        "view: back": facing < -0.5,
        "height < 150/256 of the frame": h < 150, "height 150-200/256": (h >= 150) & (h < 200),
        "height >= 200/256": h >= 200,
        "all J+ in the frame": inside == 1, "some J+ outside the frame": inside < 1,
        "no occluder": occ < 0.01, "occluder hides 1-20 %": (occ >= 0.01) & (occ < 0.2), "occluder hides >= 20 %":
            occ >= 0.2,
    }
    rows = [[k, int(m.sum()), 100 * f[m].mean() if m.any() else None] for k, m in bins.items()]
    rescued = z["rescued"][~f]
    for j, r in enumerate(z["rescues"]):
        rows.append([f"misses rescued by: {r}", int((~f).sum()), 100 * rescued[:, j].mean()])
    rows.append(["misses rescued by any of these", int((~f).sum()), 100 * rescued.any(1).mean()])
    return rows


# scikit-image's bundled sample images without a person (``camera`` and ``astronaut`` have one; the
# others need a download)
PERSON_FREE = ("brick", "chelsea", "coffee", "grass", "gravel", "rocket", "cat", "clock", "coins", "colorwheel", "moon",
               "page", "text", "hubble_deep_field", "immunohistochemistry", "retina", "checkerboard", "horse", "logo",
               "microaneurysms", "shepp_logan_phantom", "binary_blobs", "cell")


def person_free_images() -> dict[str, np.ndarray]:
    """The person-free sample images as RGB uint8, plus seven of uniform noise: 30 images."""
    out = {}
    for name in PERSON_FREE:
        im = np.asarray(getattr(skimage.data, name)())
        if im.dtype == bool:
            im = im.astype(np.uint8) * 255
        elif im.dtype != np.uint8:
            im = (255 * (im - im.min()) / max(float(np.ptp(im)), 1e-9)).astype(np.uint8)
        out[name] = np.ascontiguousarray(np.repeat(im[..., None], 3, 2) if im.ndim == 2 else im[..., :3])
    rng = np.random.default_rng(0)
    out |= {f"noise-{i}": rng.integers(0, 256, (320, 320, 3), dtype=np.uint8) for i in range(7)}
    return out


def phantom_rows() -> list[list]:
    """Bodies MediaPipe "finds" in images without a person, without and with its retries."""
    images = person_free_images()
    rows = []
    for retry in (False, True):
        # MediaPipe's own answers (the guard: eval/phantoms.py), full landmark model as committed
        src = MediaPipeSource(retry=retry, guard=False, model="full")
        found = [n for n, im in images.items() if src(im, camera.default_intrinsics(*im.shape[:2])) is not None]
        rows.append(["with retries" if retry else "first answer only", len(images), len(found), ", ".join(found)])
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--lifter", default=None, help="lifter weights (default: the shipped file, if any)")
    ap.add_argument("--out", default=str(report.RESULTS / "error-budget"))
    a = ap.parse_args()
    torch.set_num_threads(1)
    body = default_body()
    smplr = SMPLR.load(body)
    lifter = Lifter.load(a.lifter) if a.lifter or LIFTER_WEIGHTS.exists() else None
    files, routes, misses = {}, {}, {}
    for bench, n_mp, tag in (("synth-val", 2000, ""), ("synth-wide-val", 1000, " (wide)")):
        ds = SynthDataset(bench_dir(bench))
        size = ds[0]["rgb"].shape[0]
        for name, fname in (("mediapipe + adapter", f"mediapipe-{bench}-{n_mp}.npz"),
                            ("backbone, own crop", f"backbone-{bench}-500.npz"),
                            ("backbone, GT crop", f"backbone-gtcrop-{bench}-500.npz")):
            z = load(fname)
            if z is None:
                continue
            files[name + tag] = (z, size)
            ks = np.stack([ds[i]["K"] for i in range(len(z["found"]))]).astype(np.float64)
            f = z["found"]
            if name.startswith("mediapipe"):
                routes["GT 2D" + tag] = (z["gt_points2d"], None, ks, z["gt_points3d"], size)
                misses[bench] = miss_rows(z, ds)
            short = name.split(" +")[0]
            routes[f"{short} 2D{tag}"] = (z["points2d"][f], None, ks[f], z["gt_points3d"][f], size)
            routes[f"{short} 3D{tag}"] = (z["points2d"][f], z["points3d"][f], ks[f], z["gt_points3d"][f], size)
    data = {"sources": source_rows(files), "lifting": lift_rows(smplr, lifter, routes), "misses": misses,
            "person_free": phantom_rows()}
    report.write(Path(a.out), data, render(data))
    print(render(data))


SOURCE_COLS = ["source", "images", "found %", "2D px", "median px", "% box", "% box, in frame", "% box, outside",
               *GROUPS]


def render(d: dict) -> str:
    return "\n".join([
        "# Error budget on synth-val (issue 27, step 1)", "",
        "`eval/error_budget.py` (after `eval/collect_sources.py`). synth-val: 2,000 images of the val "
        "subjects, 256 x 256 (the backbone rows on its first 500); synth-wide-val (wide): 1,000 images of "
        "the same subjects framed as photos are, 512 x 512, people 30-90 % of the height, anywhere in the "
        "middle 60 % of the frame. Never used for a test number.", "",
        "## What it chose", "",
        "- Lifting (section 2, ground-truth 2D): SMPLR's DAE-2D reads orthographic metric 2D; on perspective "
        "images the camera-aware lifter (rays + K) roughly halves its error, and SMPLR should then run without "
        "the 3D DAE (the DAE smooths clean input). -> `recon.smplr.lifter`; the `smplr-gt2d` oracle.",
        "- With a real source's 2D, the 2D error dominates (compare the GT 2D and source 2D rows): the lifter "
        "alone is about as good as the source's own 3D guess, and their mean is better than either on both "
        "framings. -> `recon run --lift blend` (default).",
        "- Misses (section 3) follow occluders and people cut by the frame, hardly view or size; zero-padded "
        "views and a lower detection threshold rescue most of them. -> MediaPipe's retries "
        "(`recon.keypoints.sources.RETRIES`).",
        "- The largest remaining term is the 2D keypoints themselves (section 1: MediaPipe + adapter are "
        "5-7 % of the box height off, wrists and feet worst): better 2D, not better lifting, is what "
        "`recon run` needs next.", "",
        "## 1. 2D error of the keypoint sources (J+ points, found images)", "",
        "% box = error / the person's box height (ground-truth J+). Per joint group: % box.", "",
        report.table(d["sources"], SOURCE_COLS, ["", "", ".1f", ".1f", ".1f", ".1f", ".1f", ".1f"] + [".1f"] * 9), "",
        "## 2. Lifting: from 2D (or a source's 3D) to the body", "",
        "MPJPE in mm (24 joints, pelvis-aligned; PA = Procrustes). Pelvis depth error: the body placed by "
        "least-squares reprojection (`recon.camera.place`), or the lifter's own depth.", "",
        report.table(d["lifting"], ["2D / 3D in", "lifting", "images", "MPJPE-P1", "PA", "depth err median mm",
                                    "depth err mean mm", "lifter depth median mm"],
                     ["", "", "", ".1f", ".1f", ".0f", ".0f", ".0f"]), "",
        "## 3. Where MediaPipe finds nobody (the default source, before its retries)", "",
        *[line for bench, rows in d["misses"].items() for line in (
            f"{bench}:", "", report.table(rows, ["images", "n", "found % (rescued % for the misses rows)"],
                                          ["", "", ".1f"]), "")],
        "Rescues, each tried on every miss: upscale2 = the image at twice its size; pad1.5 = zero-padded to 1.5x its "
        "size (the person smaller in the frame); gtbox = the ground-truth person box cropped and upscaled (the "
        "ceiling of a detector feeding MediaPipe a crop); conf0.2 = detection threshold 0.2 instead of 0.5.", "",
        "## 4. Bodies in images without a person (MediaPipe + adapter)", "",
        "scikit-image's 23 bundled sample images without a person and seven of uniform noise. The retries rescue "
        "people and also invent some: rejecting phantoms is issue 28's; `recon run --no-retry` turns the "
        "retries off.", "",
        report.table(d.get("person_free", []), ["MediaPipe", "images", "bodies", "in"], ["", "", "", ""]),
    ])


if __name__ == "__main__":
    main()
