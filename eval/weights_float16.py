"""Would float16 storage change a published number? For each shipped model, its floating
parameters are rounded to float16 (and read back into float32, as a loader does) and the check
slices of the results it feeds (tests/test_results.py) are recomputed.

    OMP_NUM_THREADS=1 .venv/bin/python eval/weights_float16.py      # ~6 min on the 2-core CPU

-> eval/results/weights-float16.{json,md}. The weights files keep float32 wherever a slice
moves by as much as the published rounding; the trainers write what this table allows.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import torch

import recon.backbone.calibrate as backbone_calibrate
import recon.backbone.model as backbone_model
import recon.keypoints.adapter as adapter
import recon.smplr.model as smplr_model
from recon import report
from recon.garment import store

RESULTS = Path(__file__).resolve().parent / "results"


def rounded(src: Path, dst: Path, keys: set[str], keep: tuple[str, ...] = ()) -> tuple[int, int]:
    """A copy of a weights file with the floating tensors under ``keys`` in float16 (except
    ``keep``); returns (bytes before, bytes after)."""
    ck = torch.load(src, map_location="cpu", weights_only=True)

    def half(x):
        if torch.is_tensor(x) and x.is_floating_point():
            return x.half()
        return {k: v if k in keep else half(v) for k, v in x.items()} if isinstance(x, dict) else x

    torch.save({k: half(v) if k in keys else v for k, v in ck.items()}, dst)
    return src.stat().st_size, dst.stat().st_size


def largest_changes(expected, actual, path=""):
    if isinstance(expected, dict):
        return [c for k in expected for c in largest_changes(expected[k], actual[k], f"{path}/{k}")]
    if isinstance(expected, list):
        return [c for i, (a, b) in enumerate(zip(expected, actual, strict=True))
                for c in largest_changes(a, b, f"{path}[{i}]")]
    return [(abs(expected - actual), path)] if isinstance(expected, float) else []


def recompute(name: str) -> tuple[float, str]:
    """The largest change of a results file's check slice, and where."""
    return max(largest_changes(*report.recompute_check(RESULTS / name)))


def main() -> None:
    torch.set_num_threads(1)
    tmp = Path(tempfile.mkdtemp())
    rows = []

    def measure(model, sizes, results):
        for name in results:
            change, where = recompute(name)
            rows.append([model, f"{sizes[0] / 1e6:.1f} -> {sizes[1] / 1e6:.1f} MB", name, change, where])
            print(rows[-1], flush=True)

    for model, module, keys, results in (
            ("SMPLR", smplr_model, {"omega", "psi", "dae3d", "dae2d"}, ["smplr_anny", "synth-test"]),
            ("MediaPipe adapter", adapter, {"state"}, ["synth-test"]),
            ("backbone", backbone_model, {"net"}, ["synth-test", "backbone-crop-search"])):
        shipped = module.WEIGHTS
        sizes = rounded(shipped, tmp / shipped.name, keys)
        module.WEIGHTS = backbone_calibrate.WEIGHTS = tmp / shipped.name  # (the check names the backbone's file)
        measure(model, sizes, results)
        module.WEIGHTS, backbone_calibrate.WEIGHTS = shipped, backbone_model.WEIGHTS
    shipped = store.SHIPPED_DIR
    for kind, keep, model, results in (
            ("pbns", ("rest", "D"), "PBNS (but its rest shape; D is float16 already)",
             ["garment-pbns", "garment-reference-top-shorts"]),
            ("resize", (), "outfit resizers", ["garment-resize-tshirt-trousers", "garment-resize-dress"])):
        d = tmp / kind
        d.mkdir()
        sizes = [0, 0]
        for f in shipped.glob("*.pt"):
            if f.name.startswith(kind):
                sizes = [x + y for x, y in zip(sizes, rounded(f, d / f.name, {"state"}, keep), strict=True)]
            else:
                (d / f.name).write_bytes(f.read_bytes())
        store.SHIPPED_DIR = d
        measure(model, sizes, results)
        store.SHIPPED_DIR = shipped
    data = {"machine": report.machine(), "rows": rows}
    md = "\n".join([
        "# float16 storage of the shipped weights: largest change of each results slice", "",
        "`eval/weights_float16.py`: each model's floating parameters rounded to float16 and read back into "
        "float32, then the check slices of the results files it feeds recomputed (tests/test_results.py: the first "
        "8 images / 64 samples / 8 poses / 16 shapes of each). Published numbers are rounded to 0.1 mm, 0.001 IoU, "
        "0.01 % and 0.01 mm: a model is stored in float16 only where the largest change stays well below that.", "",
        report.table(rows, ["model", "file size", "results slice", "largest change", "where"],
                     ["", "", "", ".2g", ""])])
    print(Path(report.write(RESULTS / "weights-float16", data, md)).read_text())


if __name__ == "__main__":
    main()
