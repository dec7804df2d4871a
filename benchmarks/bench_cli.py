"""Start-up time of the command line, side by side in one run: `recon --help`, every
`recon COMMAND --help` (flag modules without torch; the test asserts each under 0.5 s), and the
import of every command's actions (what `recon run` loads before it starts, and what a
command's help cost before 0.13). Wall clock of whole processes, interleaved rounds, the median.

    .venv/bin/python benchmarks/bench_cli.py [--rounds 10]

-> eval/results/bench-cli.{json,md}
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

from recon import report
from recon.cli import COMMANDS

OUT = Path(__file__).resolve().parent.parent / "eval" / "results"
ACTIONS = sorted({"recon.cli.actions." + m.rsplit(".", 1)[1] for m, _ in COMMANDS.values()})
EVERY_ACTION = f"import importlib; [importlib.import_module(m) for m in {ACTIONS!r}]"
RECON = str(Path(sys.executable).parent / "recon")  # the console script pip installed
VARIANTS = {"recon --help": [RECON, "--help"]} | {f"recon {c} --help": [RECON, c, "--help"] for c in COMMANDS} | {
    "every command's actions imported": [sys.executable, "-c", EVERY_ACTION]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=10)
    args = ap.parse_args()
    seconds = {k: [] for k in VARIANTS}
    for _ in range(args.rounds):
        for name, cmd in VARIANTS.items():
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            seconds[name].append(time.perf_counter() - t0)
    med = {k: statistics.median(v) for k, v in seconds.items()}
    base = med["recon --help"]
    rows = [[k, v, v / base] for k, v in med.items()]
    data = {"machine": report.machine(), "rounds": args.rounds, "median_s": med, "all_s": seconds}
    md = "\n".join([
        "# Command-line start-up", "",
        f"`benchmarks/bench_cli.py --rounds {args.rounds}`; {report.describe(data['machine'])}. Wall clock of a "
        "whole process (Python start-up included), median of interleaved rounds; ratio to `recon --help`.", "",
        report.table(rows, ["command", "seconds", "ratio"], ["", ".2f", ".1f"])])
    print(Path(report.write(OUT / "bench-cli", data, md)).read_text())


if __name__ == "__main__":
    main()
