"""Cut the short raw mocap excerpts the tests retarget (tests/data/mocap) from ../shared/data/mocap.

    .venv/bin/python scripts/make_test_clips.py [--src ../shared/data/mocap] [--seconds 1.4]

Keeps each clip's header and its first frames, and the matching rows of metadata/clips.csv (frame
count updated). Only needed again if the test clips change; the tests themselves never read
../shared.
"""
from __future__ import annotations

import argparse
import csv
import shutil
from pathlib import Path

from recon import paths

CLIPS = ("cmu_asfamc_cyun9601/subjects/02/02_01.amc", "cmu_bvh_daz_ateliercircle/subjects/05/05_01.bvh",
         "cmu_bvh_daz_salsa_beemsoft/60_lead/60_01_scaled.bvh", "cmu_bvh_3dsmax_bvh11/131/131_01.bvh",
         "animateddrawings_bvh/fair1/dab.bvh")
OUT = Path(__file__).resolve().parent.parent / "tests" / "data" / "mocap"


def cut_bvh(src: Path, dst: Path, frames: int) -> int:
    lines = src.read_text().splitlines()
    i = next(k for k, line in enumerate(lines) if line.strip().startswith("Frames:"))
    n = min(frames, int(lines[i].split()[1]))
    lines[i] = f"Frames: {n}"
    dst.write_text("\n".join(lines[:i + 2 + n]) + "\n")
    return n


def cut_amc(src: Path, dst: Path, frames: int) -> int:
    out, n = [], 0
    for line in src.read_text().splitlines():
        if line.strip().isdigit():
            n += 1
            if n > frames:
                break
        out.append(line)
    dst.write_text("\n".join(out) + "\n")
    return min(n, frames)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--src", type=Path, default=paths.shared_dir() / "data" / "mocap")
    ap.add_argument("--seconds", type=float, default=1.4)
    a = ap.parse_args()
    rows = {r["path"]: r for r in csv.DictReader(open(a.src / "metadata" / "clips.csv"))}
    kept = []
    for rel in CLIPS:
        row = dict(rows[rel])
        dst = OUT / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        frames = round(a.seconds * float(row["true_fps"] or row["header_fps"])) + 1  # + the Daz reference frame
        if rel.endswith(".amc"):
            n = cut_amc(a.src / rel, dst, frames)
            asf = next((a.src / rel).parent.glob("*.asf"))
            shutil.copy(asf, dst.parent / asf.name)
        else:
            n = cut_bvh(a.src / rel, dst, frames)
        row["frames"], row["note"] = str(n), (row["note"] + "; " if row["note"] else "") + f"first {n} frames"
        kept.append(row)
    (OUT / "metadata").mkdir(parents=True, exist_ok=True)
    with open(OUT / "metadata" / "clips.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(kept[0]))
        w.writeheader()
        w.writerows(kept)
    print(OUT)


if __name__ == "__main__":
    main()
