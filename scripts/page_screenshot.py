"""A results page photographed in headless Chromium (the README's picture of `recon demo`'s page).

    .venv/bin/python scripts/page_screenshot.py out/demo demos/previews/page.jpg
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2

from recon.page import write_page
from recon.page.chromium import Chromium


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--size", type=int, nargs=2, default=(1280, 860), metavar=("W", "H"))
    ap.add_argument("--quality", type=int, default=80)
    a = ap.parse_args()
    write_page(a.folder)
    with Chromium(size=tuple(a.size)) as c:
        c.open(a.folder / "index.html")
        c.wait_for("RECON_STATE.loaded >= Math.min(2, RECON_STATE.viewers)", timeout=180)
        time.sleep(1.0)
        shot = c.screenshot()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(a.out), shot[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, a.quality])
    print(a.out, f"{a.out.stat().st_size / 1e3:.0f} kB")


if __name__ == "__main__":
    main()
