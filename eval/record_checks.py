"""Records the check slices of results files as computed on this machine's CPU vendor (AMD and
Intel compute some apart, ``recon.kernels``; a check's plain ``values`` were recorded on AMD EPYC
machines), with the tests' settings: pinned kernels, one thread, no ../shared. Run it on a
machine of the other vendor when a slice fails only there:

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
    a = ap.parse_args()
    torch.set_num_threads(1)
    for name in a.names:
        report.record_check(report.RESULTS / name)
        print(f"{name}: recorded for {kernels.vendor()}")


if __name__ == "__main__":
    main()
