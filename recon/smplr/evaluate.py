"""SMPLR ablation on held-out mocap (test subjects) and sampled test shapes: thesis Table 2.1.

``recon smplr eval`` -> eval/results/smplr_anny.{json,md}. Rows: Psi with the true pose,
Omega with the true shape, both, + Procrustes (ALL_Proc), on noisy input without and with
the DAE, and 2D lifting. Errors in mm, root (pelvis) aligned; PA = after similarity Procrustes.
"""
from __future__ import annotations

import json
from pathlib import Path

import torch

from recon import metrics, paths
from recon.smplr import noise
from recon.smplr.data import load_or_generate
from recon.smplr.model import SMPLR, _procrustes

GROUP_ABBR = {"head": "Hd", "torso": "Ts", "shoulder": "Sr", "elbow": "Ew", "wrist": "Wt", "hip": "Hp", "knee": "Kn", "foot": "Ft"}
NOISE_MM = 40.0
TEST_SEED = 777


def _rows(model: SMPLR, data, chunk: int = 250) -> dict[str, dict]:
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
    acc = {k: {"joint": [], "lm": [], "pve": [], "pa": [], "bone": [], "gender": [], "input": [], "fed": []} for k in specs}
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
                    o = _procrustes(o, out.points_in)
                a = acc[name]
                a["joint"].append(metrics.per_point_error(o.joints, gt.joints))
                a["lm"].append((o.landmarks - o.joints[:, :1] - gt.landmarks + gt.joints[:, :1]).norm(dim=-1))
                a["pve"].append((o.vertices - o.joints[:, :1] - gt.vertices + gt.joints[:, :1]).norm(dim=-1).mean(1))
                a["pa"].append(metrics.per_point_error(metrics.procrustes_align(o.joints, gt.joints), gt.joints, None).mean(1))
                a["bone"].append(metrics.bone_length_error(o.joints, gt.joints, per_sample=True))
                a["gender"].append(((shape[:, 0] > 0.5) == (data["shape"][sl, 0] > 0.5)).float())
                fed = out.points_in - out.points_in[:, :1] - data["points"][sl] + data["points"][sl, :1]
                a["fed"].append(fed.norm(dim=-1).mean(1))
                a["input"].append((x - data["points"][sl]).norm(dim=-1).mean(1) if mode == "3d" else torch.zeros(x.shape[0]))
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


def _latency(model: SMPLR, points: torch.Tensor, repeats: int = 50) -> dict[str, float]:
    x = points[:1]

    from recon.bench.timing import median_ms

    def med(fn):
        return median_ms(fn, repeats)

    with torch.no_grad():
        nets = med(lambda: model.regress(model.dae3d(x - x[:, :1])))
        full = med(lambda: model(x))
    return {"networks (DAE+Omega+Psi) ms": nets, "full SMPLR incl. mesh ms": full}


def evaluate_and_report(n: int = 2000, out_dir: Path = Path("eval/results"), weights: Path | None = None) -> Path:
    torch.set_num_threads(1)
    model = SMPLR.load(path=weights)
    data = load_or_generate(model.body, "test", n, TEST_SEED, 0.0)
    table = _rows(model, data)
    lat = _latency(model, data["points"])
    from recon.poses.mocap import SPLIT_SUBJECTS

    result = {"samples": n, "split": "test (CMU subjects %s)" % ", ".join(sorted(SPLIT_SUBJECTS["test"])),
              "noise_mm": NOISE_MM, "rows": table, "latency_batch1_cpu_1thread": lat}
    out_dir.mkdir(parents=True, exist_ok=True)
    js, md = out_dir / "smplr_anny.json", out_dir / "smplr_anny.md"
    paths.atomic_write(js, lambda t: Path(t).write_text(json.dumps(result, indent=1)))
    cols = list(GROUP_ABBR.values()) + ["Jt", "PA-Jt", "Lm", "PVE", "Bn", "gender acc", "input err", "J+ to Omega/Psi err"]
    lines = [f"SMPLR on {n} held-out samples ({result['split']}; poses unperturbed, shapes from the anny prior, "
             f"random camera views). Errors in mm, pelvis-aligned; PA = Procrustes-aligned joints; "
             f"'input err' = mean J+ error given to SMPLR; "
             f"'J+ to Omega/Psi err' = after the DAE (pelvis-aligned).", "",
             "| model | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    for name, row in table.items():
        lines.append(f"| {name} | " + " | ".join(f"{row[c]:.3f}" if c == "gender acc" else f"{row[c]:.1f}" for c in cols) + " |")
    lines += ["", "Latency, batch 1, CPU, 1 thread: " + ", ".join(f"{k}: {v:.2f}" for k, v in lat.items())]
    paths.atomic_write(md, lambda t: Path(t).write_text("\n".join(lines) + "\n"))
    print("\n".join(lines))
    return md
