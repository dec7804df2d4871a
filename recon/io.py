"""Image input for the pipeline: any file Pillow reads -> (H, W, 3) uint8 RGB, or a clear error;
and the listing of the files and folders a user gives, where every file seen is accounted for.

Handles EXIF orientation (phone photos), grayscale, palette, RGBA (composited on white), CMYK,
16-bit and float images (rescaled to 8 bits), HEIC/HEIF where pillow-heif is installed, and JPEGs
that lack only their end marker; refuses truncated or non-image files, images too small to hold a
person and images too large to decode safely, each with its reason.
"""
from __future__ import annotations

import errno
import hashlib
import io
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from recon.errors import MissingFile, ReconError

try:  # HEIC/HEIF (phone photos) through the optional pillow-heif plugin
    from pillow_heif import register_heif_opener
except ImportError:  # pragma: no cover - depends on the installation
    register_heif_opener = None
if register_heif_opener is not None:
    register_heif_opener()

MIN_SIDE = 32
MAX_PIXELS = 100_000_000  # larger images are refused before decoding (decompression bombs)
FULL_FRAME_DIAGONAL_MM = 43.27  # 36 x 24 mm: what "35 mm equivalent" focal lengths refer to
EXIF_IFD, FOCAL_35MM = 0x8769, 0xA405
JPEG_EOI = b"\xff\xd9"
HEIF_BRANDS = (b"heic", b"heix", b"heim", b"heis", b"hevc", b"hevx", b"mif1", b"msf1", b"avif")


class ImageError(ReconError):
    """The file is not a usable image; the message says why."""


def load_image(path: str | Path, data: bytes | None = None) -> np.ndarray:
    """Any file Pillow reads -> (H, W, 3) uint8 RGB, upright (EXIF); ImageError otherwise.
    ``data``: the file's bytes, already read (by a driver for a worker on another machine)."""
    path = Path(path)
    if data is None:
        if not path.is_file():
            raise ImageError(f"{path}: not a file")
        data = _read(path)
    if not data:
        raise ImageError(f"{path}: empty file")
    try:
        rgb = _decode(data)
    except ImageError as e:
        raise ImageError(f"{path}: {e}") from None
    except Image.DecompressionBombError as e:
        raise ImageError(f"{path}: too many pixels to decode safely (a decompression bomb?): {e}") from e
    except UnidentifiedImageError as e:
        if _is_heif(data) and register_heif_opener is None:
            raise ImageError(f"{path}: unsupported: HEIC/HEIF needs pillow-heif (pip install pillow-heif)") from e
        raise ImageError(f"{path}: not an image Pillow can read") from e
    except (OSError, SyntaxError, ValueError, EOFError) as e:
        raise ImageError(f"{path}: corrupt or truncated image ({e})") from e
    if min(rgb.shape[:2]) < MIN_SIDE:
        raise ImageError(f"{path}: {rgb.shape[1]}x{rgb.shape[0]} is too small (min side {MIN_SIDE} px)")
    return rgb


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as e:
        raise ImageError(f"{path}: cannot read ({e.strerror or e})") from e


def _decode(data: bytes) -> np.ndarray:
    try:
        return _open(data)
    except OSError as e:
        # a JPEG whose data is complete but whose end marker is missing: decode what is there,
        # unless the decoder had to fill the last rows (libjpeg's mid-grey for missing data)
        if "truncated" not in str(e) or not data.startswith(b"\xff\xd8") or data.endswith(JPEG_EOI):
            raise
        rgb = _open(data + JPEG_EOI)
        if (rgb[-8:] == 128).all():
            raise
        return rgb


def _open(data: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as im:
        w, h = im.size
        if w * h > MAX_PIXELS:
            raise ImageError(f"{w}x{h} is larger than {MAX_PIXELS // 1_000_000} Mpx")
        im.load()  # decodes now: truncated files raise here, not later
        return _to_rgb8(ImageOps.exif_transpose(im))


def _is_heif(data: bytes) -> bool:
    return data[4:8] == b"ftyp" and data[8:12] in HEIF_BRANDS


def exif_focal_factor(path: str | Path, data: bytes | None = None) -> float | None:
    """The camera's focal length in units of the image's longer side, from the EXIF tag
    FocalLengthIn35mmFilm (phones and most cameras write it); None when the file has none.
    The 35 mm equivalent maps the image diagonal to the 43.27 mm full-frame diagonal.
    ``data``: the file's bytes, already read."""
    try:
        with Image.open(path if data is None else io.BytesIO(data)) as im:
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


def file_digest(path: str | Path) -> str:
    """sha256 of a file's bytes (what a result was made from)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


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


# --- the files a user gives ------------------------------------------------------------------------

MAX_NAME_BYTES = 200  # an output folder name longer than this (in UTF-8) is shortened with a hash


@dataclass(frozen=True)
class Input:
    """One file to reconstruct and the output folder name (``key``) that is its own."""

    path: Path
    key: str


@dataclass
class Scan:
    """What ``scan_inputs`` found: the files to try (content decides whether they are images) and
    every other entry seen, with the reason it is not tried."""

    files: list[Input] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)  # path -> reason


def scan_inputs(inputs: list[str | Path]) -> Scan:
    """Files and folders (recursively) -> every regular file as an ``Input``, with an output key
    that no other file of the scan shares (also on case-insensitive file systems): the path
    relative to its input folder without its suffix; where two files would share one, the suffix
    is kept (``a.jpg`` -> ``a_jpg``), then the input folder's name is put in front, then a number
    appended. Hidden files inside folders, broken links, link loops, missing paths and a file given
    twice are listed in ``skipped``; MissingFile when no input exists at all."""
    scan, found, seen = Scan(), [], {}
    for n, inp in enumerate(map(Path, inputs)):
        if inp.is_dir():
            found += [(p, p.relative_to(inp), n, inp) for p in _walk(inp, scan.skipped)]
        elif inp.is_file():
            found.append((inp, Path(inp.name), n, inp.parent))
        else:
            scan.skipped[str(inp)] = _not_found_reason(inp)
    if inputs and not found and all(r == NOT_FOUND for r in scan.skipped.values()):
        raise MissingFile(f"{', '.join(map(str, inputs))}: {NOT_FOUND}")
    unique = []
    for p, rel, n, root in found:
        real = os.path.realpath(p)
        if real in seen:
            if str(p) != str(seen[real]):  # the same path given twice is simply read once
                scan.skipped[str(p)] = f"the same file as {seen[real]}"
            continue
        seen[real] = p
        unique.append((p, rel, n, root))
    keys = _unique_keys([(rel, root) for _, rel, _, root in unique])
    scan.files = [Input(p, k) for (p, *_), k in zip(unique, keys, strict=True)]
    return scan


NOT_FOUND = "no such file or folder"


def _not_found_reason(p: Path) -> str:
    """Why a path that is neither a file nor a folder cannot be read."""
    try:
        os.stat(p)
    except OSError as e:
        if e.errno == errno.ELOOP:
            return "symbolic link loop"
        if p.is_symlink():
            return "broken symbolic link"
        return NOT_FOUND if e.errno == errno.ENOENT else f"cannot read ({e.strerror or e})"
    return "not a regular file"


def _walk(root: Path, skipped: dict[str, str]) -> list[Path]:
    """Regular files below ``root`` in sorted order, following links to folders once each."""
    files, visited = [], {os.path.realpath(root)}

    def unreadable(e: OSError) -> None:
        skipped[str(e.filename)] = f"cannot read folder ({e.strerror or e})"

    for folder, dirs, names in os.walk(root, followlinks=True, onerror=unreadable):
        for d in list(dirs):
            real = os.path.realpath(os.path.join(folder, d))
            if real in visited:  # a link back up the tree, or a folder reached twice
                skipped[os.path.join(folder, d)] = "symbolic link loop (a folder already listed)"
                dirs.remove(d)
            else:
                visited.add(real)
        dirs.sort()
        for name in sorted(names):
            p = Path(folder) / name
            if name.startswith("."):
                skipped[str(p)] = "hidden file (give it by name to include it)"
            elif p.is_file():
                files.append(p)
            else:
                skipped[str(p)] = _not_found_reason(p)
    return files


def _unique_keys(entries: list[tuple[Path, Path]]) -> list[str]:
    def clashes(keys):
        count: dict[str, int] = {}
        for k in keys:
            count[k.casefold()] = count.get(k.casefold(), 0) + 1
        return [count[k.casefold()] > 1 for k in keys]

    keys = [rel.with_suffix("").as_posix() for rel, _ in entries]
    # same name, other suffix (a.jpg, a.png): keep the suffix; the same relative path from two
    # input folders is told apart by the folder's name below
    same_path = clashes([rel.as_posix() for rel, _ in entries])
    keys = [rel.with_name(rel.name.replace(".", "_")).as_posix() if c and not s else k
            for (rel, _), k, c, s in zip(entries, keys, clashes(keys), same_path, strict=True)]
    keys = [f"{root.resolve().name or 'root'}/{k}" if c else k
            for (_, root), k, c in zip(entries, keys, clashes(keys), strict=True)]
    # a key that is another's folder (a.jpg and a/p.jpg): the file's keeps its suffix
    folders = {p.casefold() for k in keys for p in _parents(k)}
    keys = [f"{k}_{Path(rel.name).suffix[1:] or 'file'}" if k.casefold() in folders else k
            for (rel, _), k in zip(entries, keys, strict=True)]
    taken, given = {k.casefold() for k in keys}, set()
    for i, k in enumerate(keys):
        j = 1
        while keys[i].casefold() in given or (j > 1 and keys[i].casefold() in taken):
            j += 1
            keys[i] = f"{k}_{j}"
        given.add(keys[i].casefold())
    return [_safe_key(k) for k in keys]


def _parents(key: str) -> list[str]:
    parts = key.split("/")
    return ["/".join(parts[:i]) for i in range(1, len(parts))]


def _safe_key(key: str) -> str:
    """Each folder name of a key within the file system's limits; long ones shortened with a hash."""
    parts = []
    for part in key.split("/"):
        raw = part.encode()
        if len(raw) > MAX_NAME_BYTES:
            digest = hashlib.sha256(raw).hexdigest()[:10]
            part = raw[:MAX_NAME_BYTES - 11].decode(errors="ignore") + "~" + digest
        parts.append(part)
    return "/".join(parts)
