"""SMPLR ablation on held-out mocap (test subjects) and sampled test shapes: thesis Table 2.1.

``recon smplr eval`` -> eval/results/smplr_anny.{json,md}. Rows: Psi with the true pose,
Omega with the true shape, both, + Procrustes (ALL_Proc), on noisy input without and with
the DAE, and 2D lifting. Errors in mm, root (pelvis) aligned; PA = after similarity Procrustes.
"""
from __future__ import annotations

from pathlib import Path

import torch

from recon import metrics, report
from recon.poses.mocap import SPLIT_SUBJECTS
from recon.smplr import noise
from recon.smplr.data import load_or_generate
from recon.smplr.model import SMPLR, align_body
from recon.timing import median_ms

GROUP_ABBR = {"head": "Hd", "torso": "Ts", "shoulder": "Sr", "elbow": "Ew", "wrist": "Wt", "hip": "Hp", "knee": "Kn",
              "foot": "Ft"}
NOISE_MM = 40.0
TEST_SEED = 777
CHECK_SAMPLES = 64  # the slice of the table tests/test_results.py recomputes
# how far its values may move between CPUs: float noise, absolute for the near-zero errors (mm)
CHECK_TOLERANCE = {"rtol": 1e-3, "atol": 1e-4}


def rows(model: SMPLR, data, chunk: int = 250) -> dict[str, dict]:
    """The table's rows (mm, pelvis-aligned) for the held-out samples ``data``."""
    body = model.body
    gen = torch.Generator().manual_seed(TEST_SEED)
    n = data["points"].shape[0]
    noisy = noise.fixed_gaussian(data["points"], NOISE_MM / 1000.0, gen)
    structured = noise.structured(data["points"], torch.Generator().manual_seed(TEST_SEED + 1))
    specs = {
        "Psi (true pose)": dict(inp="clean", use="psi", denoise=False),
        "Omega (true shape)": dict(inp="clean", use="omega", denoise=False),
        "Omega+Psi": dict(inp="clean", denoise=False),
        "Omega+Psi, Procrustes": dict(inp="clean", proc=True, denoise=False),
        "clean input, DAE": dict(inp="clean"),
        f"Gaussian {NOISE_MM:g} mm, no DAE": dict(inp="noisy", denoise=False),
        f"Gaussian {NOISE_MM:g} mm, DAE": dict(inp="noisy"),
        f"Gaussian {NOISE_MM:g} mm, DAE, Procrustes": dict(inp="noisy", proc=True),
        "structured noise, no DAE": dict(inp="structured", denoise=False),
        "structured noise, DAE": dict(inp="structured"),
        "2D lifting (depth zeroed), DAE-2D": dict(inp="clean", mode="2d"),
        "2D lifting, DAE-2D, Procrustes": dict(inp="clean", mode="2d", proc=True),
    }
    inputs = {"clean": data["points"], "noisy": noisy, "structured": structured}
    acc = {k: {m: [] for m in ("joint", "lm", "pve", "pa", "bone", "gender", "input", "fed")} for k in specs}
    with torch.no_grad():
        for i in range(0, n, chunk):
            sl = slice(i, min(i + chunk, n))
            gt = body(data["rotmats"][sl], data["shape"][sl])
            for name, sp in specs.items():
                x = inputs[sp["inp"]][sl]
                mode = sp.get("mode", "3d")
                # only rotations, shape, pelvis and J+ are used: skip the model's full mesh
                out = model(x, mode=mode, denoise=sp.get("denoise", True), points_only=True)
                rot, shape = out.rotmats, out.shape
                if sp.get("use") == "psi":
                    rot = data["rotmats"][sl]
                if sp.get("use") == "omega":
                    shape = data["shape"][sl]
                o = body(rot, shape, transl=out.body.joints[:, 0])
                if sp.get("proc"):
                    o = align_body(o, out.points_in)
                a = acc[name]
                a["joint"].append(metrics.per_point_error(o.joints, gt.joints))
                a["lm"].append((o.landmarks - o.joints[:, :1] - gt.landmarks + gt.joints[:, :1]).norm(dim=-1))
                a["pve"].append((o.vertices - o.joints[:, :1] - gt.vertices + gt.joints[:, :1]).norm(dim=-1).mean(1))
                aligned = metrics.procrustes_align(o.joints, gt.joints)
                a["pa"].append(metrics.per_point_error(aligned, gt.joints, None).mean(1))
                a["bone"].append(metrics.bone_length_error(o.joints, gt.joints, per_sample=True))
                a["gender"].append(((shape[:, 0] > 0.5) == (data["shape"][sl, 0] > 0.5)).float())
                fed = out.points_in - out.points_in[:, :1] - data["points"][sl] + data["points"][sl, :1]
                a["fed"].append(fed.norm(dim=-1).mean(1))
                given = (x - data["points"][sl]).norm(dim=-1).mean(1) if mode == "3d" else torch.zeros(x.shape[0])
                a["input"].append(given)
    table = {}
    for name, a in acc.items():
        je = torch.cat(a["joint"]) * 1000
        row = {GROUP_ABBR[g]: v for g, v in metrics.group_errors(je).items()}
        row.update({"Jt": float(je.mean()), "PA-Jt": float(torch.cat(a["pa"]).mean() * 1000),
                    "Lm": float(torch.cat(a["lm"]).mean() * 1000), "PVE": float(torch.cat(a["pve"]).mean() * 1000),
                    "Bn": float(torch.cat(a["bone"]).mean() * 1000), "gender acc": float(torch.cat(a["gender"]).mean()),
                    "input err": float(torch.cat(a["input"]).mean() * 1000),
                    "J+ to Omega/Psi err": float(torch.cat(a["fed"]).mean() * 1000)})
        table[name] = row
    return table


def _latency(model: SMPLR, points: torch.Tensor) -> dict[str, float]:
    x = points[:1]
    with torch.no_grad():
        nets = median_ms(lambda: model.regress(model.dae3d(x - x[:, :1])))
        full = median_ms(lambda: model(x))
    return {"networks (DAE+Omega+Psi) ms": nets, "full SMPLR incl. mesh ms": full}


def check(n: int = CHECK_SAMPLES, weights: Path | None = None) -> dict[str, dict]:
    """The table on the first ``n`` held-out samples (a set of its own, generated like the full one)."""
    model = SMPLR.load(path=weights)
    return rows(model, load_or_generate(model.body, "test", n, TEST_SEED, 0.0))


def evaluate_and_report(n: int = 2000, out_dir: Path = report.RESULTS, weights: Path | None = None) -> Path:
    """``recon smplr eval``: the table on ``n`` held-out samples -> ``smplr_anny.{json,md}``."""
    model = SMPLR.load(path=weights)
    data = load_or_generate(model.body, "test", n, TEST_SEED, 0.0)
    table = rows(model, data)
    result = {"samples": n, "split": f"test (CMU subjects {', '.join(sorted(SPLIT_SUBJECTS['test']))})",
              "noise_mm": NOISE_MM, "rows": table, "latency_batch1_cpu_ms": _latency(model, data["points"]),
              "threads": torch.get_num_threads(),
              "check": {"function": "recon.smplr.evaluate:check", "kwargs": {"n": CHECK_SAMPLES},
                        "values": table if n == CHECK_SAMPLES else check(CHECK_SAMPLES, weights),
                        "tolerance": CHECK_TOLERANCE}}
    return report.write(Path(out_dir) / "smplr_anny", result, render(result))


def render(result: dict) -> str:
    """The Markdown of a ``smplr_anny.json``."""
    cols = [*GROUP_ABBR.values(), "Jt", "PA-Jt", "Lm", "PVE", "Bn", "gender acc", "input err", "J+ to Omega/Psi err"]
    fmt = [""] + [".3f" if c == "gender acc" else ".1f" for c in cols]
    lat = result["latency_batch1_cpu_ms"]
    return "\n".join([
        f"SMPLR on {result['samples']} held-out samples ({result['split']}; poses unperturbed, shapes from the anny "
        "prior, random camera views). Errors in mm, pelvis-aligned; PA = Procrustes-aligned joints; 'input err' = "
        "mean J+ error given to SMPLR; 'J+ to Omega/Psi err' = after the DAE (pelvis-aligned). `recon smplr eval`.", "",
        report.table([[name] + [row[c] for c in cols] for name, row in result["rows"].items()], ["model"] + cols, fmt),
        "", f"Latency, batch 1, CPU, {result['threads']} thread(s): "
        + ", ".join(f"{k}: {v:.2f}" for k, v in lat.items())])
