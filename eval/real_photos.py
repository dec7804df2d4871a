"""Real photographs of people, by eye (issue 68): the bundled photos and the photos of people in
Debian's opencv-doc (examples/data: messi5.jpg, basketball1.png, basketball2.png; extracted by
scripts/setup.sh), through `recon run` with its defaults: the body's gender, how sure, height and
where it was found, and one contact sheet of the overlays and side views for the release note.
Writes eval/results/real-photos.{md,json} and demos/previews/real-photos.jpg.

    .venv/bin/python eval/real_photos.py [--weights shape_head.pt]   # ~1 min
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from recon import paths, report
from recon.synth.photos import photos_dir

ROOT = Path(__file__).resolve().parent.parent
OPENCV = ("messi5.jpg", "basketball1.png", "basketball2.png")
# the people in them as the photos show them (the anny gender a user would expect: 1 female, 0 male)
EXPECTED = {"astronaut.jpg": "female", "grace_hopper.jpg": "female", "cameraman.png": "male",
            "messi5.jpg": "male", "basketball1.png": "male", "basketball2.png": "male"}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(report.RESULTS / "real-photos"))
    ap.add_argument("--sheet", default=str(ROOT / "demos" / "previews" / "real-photos.jpg"))
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        photos = Path(tmp) / "photos"
        photos.mkdir()
        for f in sorted((paths.DATA_DIR / "examples").glob("*")):
            if f.suffix in (".jpg", ".png"):
                shutil.copy(f, photos / f.name)
        for name in OPENCV:
            src = photos_dir() / "opencv-doc" / "usr/share/doc/opencv-doc/examples/data" / name
            if src.exists():
                shutil.copy(src, photos / name)
        out = Path(tmp) / "out"
        subprocess.run([sys.executable, "-m", "recon.cli", "run", str(photos), "--out", str(out)], check=True,
                       capture_output=True)
        rows, tiles = [], []
        for f in sorted(photos.iterdir()):
            res = out / f.stem / "result.json"
            if not res.exists():
                rows.append([f.name, EXPECTED.get(f.name), None, None, None, None, "no person found"])
                continue
            r = json.loads(res.read_text())
            g = r["shape"]["gender"]
            rows.append([f.name, EXPECTED.get(f.name), g, r["shape_confidence"], r["height_m"], r["found_by"],
                         "female" if g > 0.5 else "male" if g < 0.5 else "-"])
            over = cv2.imread(str(out / f.stem / "overlay.png"))
            side = cv2.imread(str(out / f.stem / "side.png"))
            h = 240
            tiles.append(np.concatenate([cv2.resize(over, (int(over.shape[1] * h / over.shape[0]), h)),
                                         cv2.resize(side, (h, h))], 1))
    if tiles:
        width = max(t.shape[1] for t in tiles)
        sheet = np.concatenate([cv2.copyMakeBorder(t, 0, 4, 0, width - t.shape[1], cv2.BORDER_CONSTANT,
                                                   value=(255, 255, 255)) for t in tiles], 0)
        Path(a.sheet).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(a.sheet, sheet, [cv2.IMWRITE_JPEG_QUALITY, 80])
    md = ["# Real photographs of people through `recon run` (by eye)", "",
          "`eval/real_photos.py`: the bundled photos and the photos of people in Debian's opencv-doc "
          "(examples/data), `recon run` with its defaults. gender: anny's phenotype (1 female, 0 male); "
          "shape_confidence: |2p - 1| of the shape head's probability; height: the body's standing height "
          "(a guess from proportions: no known size, focal length assumed). Overlays and side views: "
          f"[{Path(a.sheet).name}](../../demos/previews/{Path(a.sheet).name}).", "",
          report.table(rows, ["photo", "person (as seen)", "gender", "shape_confidence", "height m", "found by",
                              "reads as"], ["", "", ".2f", ".2f", ".2f", "", ""]), "",
          report.describe(report.machine()) + "."]
    report.write(a.out, {"rows": rows}, "\n".join(md))
    print("\n".join(md))


if __name__ == "__main__":
    main()
