"""Image input for the pipeline: any file Pillow reads -> (H, W, 3) uint8 RGB, or a clear error.

Handles EXIF orientation (phone photos), grayscale, palette, RGBA (composited on white),
16-bit and float images (rescaled to 8 bits), and refuses truncated or non-image files and
images too small to hold a person or too large to decode safely.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from recon.errors import MissingFile, ReconError

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".gif", ".ppm", ".pgm")
MIN_SIDE = 32
MAX_PIXELS = 100_000_000  # larger images are refused before decoding (decompression bombs)
FULL_FRAME_DIAGONAL_MM = 43.27  # 36 x 24 mm: what "35 mm equivalent" focal lengths refer to
EXIF_IFD, FOCAL_35MM = 0x8769, 0xA405


class ImageError(ReconError):
    """The file is not a usable image; the message says why."""


def load_image(path: str | Path) -> np.ndarray:
    """Any file Pillow reads -> (H, W, 3) uint8 RGB, upright (EXIF); ImageError otherwise."""
    path = Path(path)
    if not path.is_file():
        raise ImageError(f"{path}: not a file")
    if path.stat().st_size == 0:
        raise ImageError(f"{path}: empty file")
    try:
        with Image.open(path) as im:
            w, h = im.size
            if w * h > MAX_PIXELS:
                raise ImageError(f"{path}: {w}x{h} is larger than {MAX_PIXELS // 1_000_000} Mpx")
            im.load()  # decodes now: truncated files raise here, not later
            im = ImageOps.exif_transpose(im)
            rgb = _to_rgb8(im)
    except ImageError:
        raise
    except UnidentifiedImageError as e:
        raise ImageError(f"{path}: not an image Pillow can read") from e
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as e:
        raise ImageError(f"{path}: corrupt or truncated image ({e})") from e
    if min(rgb.shape[:2]) < MIN_SIDE:
        raise ImageError(f"{path}: {rgb.shape[1]}x{rgb.shape[0]} is too small (min side {MIN_SIDE} px)")
    return rgb


def exif_focal_factor(path: str | Path) -> float | None:
    """The camera's focal length in units of the image's longer side, from the EXIF tag
    FocalLengthIn35mmFilm (phones and most cameras write it); None when the file has none.
    The 35 mm equivalent maps the image diagonal to the 43.27 mm full-frame diagonal."""
    try:
        with Image.open(path) as im:
            exif = im.getexif()
            f35 = exif.get_ifd(EXIF_IFD).get(FOCAL_35MM) or exif.get(FOCAL_35MM)
            w, h = im.size
    except (OSError, SyntaxError, ValueError, UnidentifiedImageError, Image.DecompressionBombError):
        return None
    try:
        f35 = float(f35) if f35 else 0.0
    except (TypeError, ValueError):
        return None
    if not 5.0 <= f35 <= 2000.0:  # absent, zero or nonsense
        return None
    return f35 * float(np.hypot(w, h)) / FULL_FRAME_DIAGONAL_MM / max(w, h)


def _to_rgb8(im) -> np.ndarray:
    if im.mode in ("I;16", "I;16B", "I;16L", "I", "F"):
        a = np.asarray(im, dtype=np.float64)
        hi = 65535.0 if im.mode.startswith("I;16") or a.max() > 255 else 255.0
        if im.mode == "F":
            hi = max(float(a.max()), 1e-6) if a.max() > 1.0 else 1.0
        g = np.clip(a / hi * 255.0 + 0.5, 0, 255).astype(np.uint8)
        return np.repeat(g[..., None], 3, axis=2)
    if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
        im = im.convert("RGBA")
        a = np.asarray(im, dtype=np.float32)
        alpha = a[..., 3:] / 255.0
        return (a[..., :3] * alpha + 255.0 * (1.0 - alpha) + 0.5).astype(np.uint8)
    if im.mode != "RGB":
        im = im.convert("RGB")
    return np.ascontiguousarray(np.asarray(im, dtype=np.uint8))


def list_images(inputs: list[str | Path]) -> list[tuple[Path, str]]:
    """Files and folders (recursively, image suffixes only) -> sorted [(path, output key)].
    The key is the path relative to its input folder without the suffix; when two inputs
    would share a key the suffix is kept (a.jpg -> a_jpg)."""
    found: list[tuple[Path, Path]] = []
    for inp in map(Path, inputs):
        if inp.is_dir():
            found += [(p, p.relative_to(inp)) for p in sorted(inp.rglob("*"))
                      if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".")]
        elif inp.is_file():
            found.append((inp, Path(inp.name)))  # any suffix: load_image decides
        else:
            raise MissingFile(f"{inp}: no such file or folder")
    stems: dict[str, int] = {}
    for _, rel in found:
        k = str(rel.with_suffix(""))
        stems[k] = stems.get(k, 0) + 1
    out, seen = [], set()
    for p, rel in found:
        k = str(rel.with_suffix(""))
        if stems[k] > 1:
            k = str(rel.with_name(rel.name.replace(".", "_")))
        if k in seen:  # the same file given twice
            continue
        seen.add(k)
        out.append((p, k))
    return out
