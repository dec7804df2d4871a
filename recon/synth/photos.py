"""Real photographs from Debian packages, as backgrounds of the other-domain benchmarks.

The training generator (``recon.synth.scene``) never sees these: its backgrounds are
scikit-image's photos, procedural patterns and abstract wallpapers (``TRAIN_PACKAGES``). The
other domain (``recon.synth.other``) puts its people over people-free photographs from OpenCV's and
Hugin's documentation (``OTHER_PHOTOS``). ``scripts/setup.sh`` extracts the packages' files into
``photos_dir()``; each file is checked against the first 16 hex digits of its SHA-256, so that
the benchmarks stay the same bits. The photo packages reserved for outside checks
(``RESERVED_PACKAGES``) are used by no data set of the project.
"""
from __future__ import annotations

import hashlib
from functools import cache
from pathlib import Path

import cv2
import numpy as np

from recon import paths
from recon.errors import MissingFile

RESERVED_PACKAGES = ("mate-backgrounds", "plasma-workspace-wallpapers", "lomiri-wallpapers-16.04",
                     "lomiri-wallpapers-20.04")
# (package, folder inside it, [(file, sha256 prefix)]): people-free photographs only
OTHER_PHOTOS = (
    ("opencv-doc", "usr/share/doc/opencv-doc/examples/data", (
        ("aero1.jpg", "d9a69191f6e3642e"), ("aero3.jpg", "1c407146f8762b3b"), ("aloeL.jpg", "cce5736808efe80d"),
        ("apple.jpg", "e86879de3d9a807d"), ("board.jpg", "4c9a24ba67138ad5"), ("building.jpg", "742a1baad62ac82e"),
        ("butterfly.jpg", "34a99716b78ded10"), ("fruits.jpg", "9c031d80a1c52da5"), ("graf1.png", "1504b769303c7bde"),
        ("graf3.png", "492e0e96f21748d0"), ("home.jpg", "23b8cf46a1965d0e"), ("leuvenA.jpg", "b2977cdbd9fb3f94"),
        ("leuvenB.jpg", "5bb41a60038a2baa"), ("licenseplate_motion.jpg", "ea6fa9cea75df91b"),
        ("orange.jpg", "152c20d2f380ac98"), ("rubberwhale1.png", "eb312435369dac9e"),
        ("smarties.png", "ad3f751c053fdcf4"), ("squirrel_cls.jpg", "20bb6e8ae96918a3"),
        ("starry_night.jpg", "accda7a19a90f22a"), ("stuff.jpg", "21cd00afbdd0727f"),
        ("box_in_scene.png", "8b0225ff76244a42"), ("ela_original.jpg", "b55798b35e2dcb24"))),
    ("hugin-data", "usr/share/hugin/xrc/data/help_en_EN", (
        ("600px-Tuebingen_Neckarfront_small15_2006-06-11.jpg", "cb8beb55989b6092"),
        ("Big_ben_cylindrical.jpg", "ca27540e39532c19"), ("CA_fringes00.jpg", "dc09f0151feaa78e"),
        ("CA_tCA00.jpg", "1108a76b0ee1b092"), ("Medinet_habu_horizontal_stereographic.jpg", "7d3d9d2ac96cf67d"),
        ("Barrel-distortion.jpg", "fe18321f66902195"))),
)
# Street-like photographs: the backgrounds of the crowd scenes
STREETS = ("building.jpg", "home.jpg", "leuvenA.jpg", "leuvenB.jpg",
           "600px-Tuebingen_Neckarfront_small15_2006-06-11.jpg", "CA_tCA00.jpg", "Big_ben_cylindrical.jpg", "aero3.jpg")


def photos_dir() -> Path:
    """Where scripts/setup.sh extracts the photo packages: <cache>/photos/<package>/..."""
    return paths.cache_dir() / "photos"


def photo_path(package: str, folder: str, name: str) -> Path:
    return photos_dir() / package / folder / name


def other_photo_names() -> list[str]:
    return [name for _, _, files in OTHER_PHOTOS for name, _ in files]


@cache
def load_photo(name: str) -> np.ndarray:
    """One of ``OTHER_PHOTOS`` as an (H, W, 3) uint8 RGB array, its bytes checked."""
    for package, folder, files in OTHER_PHOTOS:
        for n, digest in files:
            if n != name:
                continue
            p = photo_path(package, folder, n)
            if not p.is_file():
                raise MissingFile(f"{p} not found: scripts/setup.sh extracts Debian's {package} package there")
            data = p.read_bytes()
            if hashlib.sha256(data).hexdigest()[:16] != digest:
                raise MissingFile(f"{p} is not the file the benchmarks were made from (another {package} version); "
                                  "re-run scripts/setup.sh")
            im = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
            return np.ascontiguousarray(im[..., ::-1])
    raise KeyError(name)


def available() -> bool:
    """Whether every photo of ``OTHER_PHOTOS`` is installed."""
    return all(photo_path(p, f, n).is_file() for p, f, files in OTHER_PHOTOS for n, _ in files)
