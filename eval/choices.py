"""The choices of 0.12's `recon run` defaults, each as a paired comparison on other-val (issue 68:
a default changes only if other-val does not get worse), and the release against 0.11 on
other-test. Reads the per-image numbers of ``recon eval`` runs (``eval/compare.py``); writes
eval/results/choices.{json,md}.

    .venv/bin/recon eval --bench other-val --workers 2 --method recon-run recon-run-0.11 \\
        "recon-run[search=False]" "recon-run[flip=False]" "recon-run[fit_steps=0]" ...
    .venv/bin/python eval/choices.py
"""
from __future__ import annotations

import sys
from pathlib import Path

from recon import report

sys.path.insert(0, str(Path(__file__).resolve().parent))
from compare import compare  # noqa: E402

# (benchmark, A, B, what the comparison decided)
CHOICES = [
    ("other-val", "recon-run-0.11", "recon-run[search=False]",
     "the backbone leaves the defaults (no fallback, blend weight 0)"),
    ("other-val", "recon-run[search=False]", "recon-run", "the faceless person search is on"),
    ("other-val", "recon-run-0.12-no-mirror-check", "recon-run",
     "the search's mirror check (fewer bodies on person-free frames: person-search.md)"),
    ("other-val", "recon-run[T=1]", "recon-run", "the shape head's gender temperature 3.4"),
    ("other-val", "recon-run[flip=False]", "recon-run", "flip averaging stays"),
    ("other-val", "recon-run[fit_steps=0]", "recon-run", "the fit stays"),
    ("other-val", "recon-run[fit_steps=15]", "recon-run", "the fit keeps 30 steps"),
    ("other-val", "recon-run[keypoint_model='full']", "recon-run", "the heavy landmark model stays"),
    ("other-val-gray", "recon-run-0.12-tinted-gray-search", "recon-run",
     "grayscale photos: the faceless search on the gray image first, then tinted"),
    ("other-test", "recon-run-0.11", "recon-run", "0.12's defaults against 0.11's (reported, not chosen on)"),
]


def main() -> None:
    rows, data = [], []
    for bench, a, b, what in CHOICES:
        c = compare(bench, a, b)
        data.append({**c, "decision": what})
        p1, p2 = c["p1"]["diff"], c["p2"]["diff"]
        rows.append([bench, what, a, b, f"{c['found_a']:.1%} -> {c['found_b']:.1%}", c["both"],
                     f"{p1[0]:+.1f} [{p1[1]:+.1f}, {p1[2]:+.1f}]", f"{p2[0]:+.1f} [{p2[1]:+.1f}, {p2[2]:+.1f}]"])
    md = "\n".join([
        "Each default of `recon run` (0.12) as a paired comparison of B against A: people found by each, "
        "and on the images both found the mean difference B - A in mm with its 95 % bootstrap interval "
        "(10,000 resamples). Chosen on other-val; other-test is the report. `eval/choices.py`. "
        "`recon-run[T=1]` was run with `recon.shape.head.GENDER_TEMPERATURE` set to 1; "
        "`recon-run-0.12-tinted-gray-search`: the search on tinted gray images only (the first 300 images); "
        "`recon-run-0.12-no-mirror-check`: the search without its mirror check. The variants below the "
        "mirror check's row were run before it (with the search as it was then); on the images both "
        "found, MediaPipe's detector found nearly all of them, where the check changes nothing.", "",
        report.table(rows, ["bench", "decision", "A", "B", "found", "both", "MPJPE-P1 B - A", "PA B - A"])])
    print(md)
    report.write(report.RESULTS / "choices", data, md)


if __name__ == "__main__":
    main()
