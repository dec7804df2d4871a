"""Re-records the check slices of results files (their ``values``) with the tests' settings:
pinned kernels, one thread, no ../shared. For a change that moves a slice by float noise only (a
refactor, another weights file whose table was re-run); never to make a failing check pass:

    RECON_SHARED_DIR=$(mktemp -d) .venv/bin/python eval/record_checks.py synth-test synth-wide-test
"""
from __future__ import annotations

import argparse
import os

from recon import kernels

kernels.pin()
os.environ.setdefault("OMP_NUM_THREADS", "1")  # as tests/conftest.py
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import torch  # noqa: E402

from recon import report  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("names", nargs="+", help="results files under eval/results, without suffix")
    args = ap.parse_args()
    torch.set_num_threads(1)
    for name in args.names:
        report.record_check(report.RESULTS / name)
        print(f"{name}: recorded")


if __name__ == "__main__":
    main()
