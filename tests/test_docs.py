"""The README and docs stay true: the README's results table is the results file's, links point
at files that exist, the README stays short, and the documented commands parse."""
import json
import re
import shlex
from pathlib import Path

import pytest
import torch

from recon.cli import build_parser

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
PAGES = [README, ROOT / "CHANGELOG.md", ROOT / "eval" / "README.md", *DOCS,
         *sorted(ROOT.glob("recon/*/weights/*CARD.md"))]
# README rows -> the method they quote on other-test and synth-test
ROWS = {"`recon run` (0.28": "recon-run", "`recon run` of 0.11": "recon-run-0.11",
        "`recon run --source backbone`": "backbone-smplr-fit", "MediaPipe's own 3D": "mediapipe",
        "oracle:": "smplr-gt2d"}


def test_the_readme_is_short_and_links_the_stage_pages():
    text = README.read_text()
    assert len(text) <= 10_000
    for page in ("install", "body", "poses", "smplr", "synth", "pipeline", "backbone", "garments", "training",
                 "benchmarks", "animate", "video"):
        assert (ROOT / "docs" / f"{page}.md").exists(), page
        assert f"(docs/{page}.md)" in text, page


def test_the_readme_results_table_is_the_results_files():
    results = {bench: {r["method"]: r for r in json.loads((ROOT / f"eval/results/{bench}.json").read_text())["rows"]}
               for bench in ("other-test", "synth-test")}
    rows = [line for line in README.read_text().splitlines() if line.startswith("| ") and "MPJPE" not in line]
    seen = set()
    for line in rows:
        cells = [c.strip() for c in line.strip("|").split("|")]
        method = next((m for label, m in ROWS.items() if cells[0].startswith(label)), None)
        if method is None:
            continue
        seen.add(method)
        expected = []
        for bench in ("other-test", "synth-test"):
            r = results[bench][method]
            found = f"{1 - r['failures'] / r['images']:.1%}" + ("" if r["images"] >= 1000 else f" of {r['images']}")
            expected += [format(r["MPJPE-P1"], ".1f"), format(r["MPJPE-P2 (PA)"], ".1f"), found]
        assert cells[1:7] == expected, (method, cells[1:7], expected)
    assert seen == set(ROWS.values())


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_point_at_files(page):
    for target in re.findall(r"\]\(([^)#\s]+)", page.read_text()):
        if "://" in target:
            continue
        assert (page.parent / target).exists(), f"{page.name} links {target}"


def test_documented_recon_commands_parse(monkeypatch):
    """Every `recon ...` line in a shell block of the README and docs is accepted by the parser
    (on a machine with a GPU: the GPU recipe's lines name one)."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    parser = build_parser()
    count = 0
    for page in [README, *DOCS]:
        for block in re.findall(r"```bash\n(.*?)```", page.read_text(), re.S):
            for line in block.replace("\\\n", " ").splitlines():
                line = line.split("#")[0].strip()
                for part in line.split("&&"):
                    words = shlex.split(part)
                    if words and words[0].endswith("recon"):
                        if "--help" in words or "..." in part:
                            continue
                        parser.parse_args(words[1:])
                        count += 1
    assert count > 20
