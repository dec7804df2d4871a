"""The worker of ``recon run``: reconstructs batches of images (in the driver's process, a local
worker process or a Ray actor) and returns each image's folder as files (``recon.run.files``)."""
from __future__ import annotations

import logging
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from recon import camera
from recon.errors import ReconError
from recon.garment.dress import Dresser
from recon.io import ImageError, exif_focal_factor, load_image
from recon.pipeline import Reconstructor
from recon.reconstruction import NoPersonFound, ReconstructorConfig
from recon.run.files import write_one, write_people

MAX_SIDE = 1920  # longer side used for detection/rendering; results are in original pixels
log_ = logging.getLogger(__name__)


@dataclass
class RunOptions:
    """What ``recon run`` makes of each image besides the reconstruction (``ReconstructorConfig``).

    outfit: dress the bodies with a trained outfit, resized to each body; tightness: (2,) looser
    (> 0) or tighter (< 0), needs the outfit's resizer. max_people: people per image (> 1: the
    ``person_<i>/`` layout). overlay: write overlay.png and side.png. exif_focal: the focal length
    from the photo's EXIF where it has one (else the config's ``focal_factor``). batch_size: images
    per SMPLR/fit batch. force: make every image again, even those already done. garment_model:
    "pbns" or "taylor" (recon.garment.Dresser). all_influences: the .glb files keep every joint
    influence of a vertex (default: the 4 strongest, which engines read).
    """

    outfit: str | None = None
    tightness: tuple[float, float] | None = None
    max_people: int = 1
    overlay: bool = True
    exif_focal: bool = True
    batch_size: int = 4
    force: bool = False
    garment_model: str = "pbns"
    all_influences: bool = False

    def to_json(self) -> dict:
        """The options that change the outputs (not batch size or force; the garment model only
        when it is not the default, so that earlier runs' outputs stay theirs)."""
        d = asdict(self)
        d["tightness"] = None if self.tightness is None else [float(t) for t in self.tightness]
        skip = ("batch_size", "force") + (("garment_model",) if self.garment_model == "pbns" else ()) + (
            () if self.all_influences else ("all_influences",))
        return {k: v for k, v in d.items() if k not in skip}


@dataclass
class Job:
    """One image to reconstruct into ``<out>/<key>/``; ``data``: the file's bytes, read by the
    driver when the worker may be on another machine (``error``: why they could not be read)."""

    path: str
    key: str
    stamp: dict
    data: bytes | None = None
    error: str | None = None


@dataclass
class Outcome:
    """What became of a Job: "done" (``files``: the image folder, relative path -> bytes),
    "no_person", "skipped" or "failed" (``message``: why)."""

    path: str
    key: str
    status: str
    message: str = ""
    files: dict[str, bytes] | None = None


class RunWorker:
    """Reconstructs batches of Jobs (in this process, a worker process or a Ray actor): builds its
    Reconstructor when the first image needs it, writes each image folder in a temporary folder
    and returns its files."""

    def __init__(self, options: RunOptions, config: ReconstructorConfig, reconstructor: Reconstructor | None = None,
                 dresser: Dresser | None = None):
        self.options, self.config, self.rec = options, config, reconstructor
        self.dresser = dresser if dresser is not None else dresser_for(options)

    def __call__(self, batch: list[Job]) -> list[Outcome]:
        outcomes: dict[str, Outcome] = {}
        loaded = []
        for job in batch:
            try:
                if job.error:
                    raise ImageError(f"{job.path}: {job.error}")
                loaded.append((job, load_image(job.path, job.data)))
            except ImageError as e:
                outcomes[job.key] = Outcome(job.path, job.key, "skipped", _reason(e, Path(job.path)))
        if loaded:
            self.rec = self.rec or Reconstructor(self.config)
            rec, options = self.rec, self.options
            small = [_downscale(img) for _, img in loaded]
            focal = [(exif_focal_factor(job.path, job.data) if options.exif_focal else None) for job, _ in loaded]
            ks = [np.diag([s, s, 1.0]) @ camera.default_intrinsics(*img.shape[:2], f or rec.focal_factor)
                  for (_, img), (_, s), f in zip(loaded, small, focal, strict=True)]
            try:
                results = rec.people([im for im, _ in small], ks, options.max_people)
            except (KeyboardInterrupt, ReconError):
                raise
            except Exception as e:  # noqa: BLE001 - one batch's bug must not stop a folder of thousands
                log_.debug("reconstruction failed", exc_info=True)
                results = [e] * len(loaded)
            for (job, img), (im, s), k, r, f in zip(loaded, small, ks, results, focal, strict=True):
                outcomes[job.key] = self._finish(job, img, im, s, k, r, "exif" if f else "default")
        return [outcomes[job.key] for job in batch]

    def _finish(self, job: Job, img, small, s: float, k, result, focal_from: str) -> Outcome:
        """One image's folder written in a temporary folder and read back as its files."""
        if isinstance(result, NoPersonFound):
            return Outcome(job.path, job.key, "no_person")
        if isinstance(result, Exception):
            return Outcome(job.path, job.key, "failed",
                           f"reconstruction failed: {result!r} (a bug: please report it; -v shows more)")
        options = self.options
        with tempfile.TemporaryDirectory(prefix="recon-run-") as tmp:
            folder = Path(tmp) / "image"
            try:
                people = result if options.max_people > 1 else result[:1]
                write = write_people if options.max_people > 1 else write_one
                write(folder, Path(job.path), img, small, s, k, people, self.rec, options, self.dresser, focal_from,
                      job.stamp)
                files = {p.relative_to(folder).as_posix(): p.read_bytes()
                         for p in sorted(folder.rglob("*")) if p.is_file()}
            except OSError as e:
                return Outcome(job.path, job.key, "failed", f"cannot write outputs ({e.strerror or e})")
        return Outcome(job.path, job.key, "done", files=files)


def dresser_for(options: RunOptions) -> Dresser | None:
    """The outfit's Dresser, refused before any image when the outfit or its resizer is missing."""
    if not options.outfit:
        if options.tightness is not None:
            raise ReconError("--tightness needs --outfit")
        return None
    dresser = Dresser(options.outfit, garment_model=options.garment_model)
    if options.tightness is not None and not dresser.garment.resizes:
        raise ReconError(f"--tightness is the resizer's: the {dresser.garment.label} garment model has none")
    if options.tightness is not None and not dresser.has_resizer:
        raise ReconError(f"--tightness needs a trained resizer for {options.outfit}: "
                         f"run `recon garment resize --outfit {options.outfit}`")
    return dresser


def _reason(e: Exception, path: Path) -> str:
    """An error's message without the path in front (the summary lists it by path)."""
    msg = str(e)
    return msg[len(str(path)) + 2:] if msg.startswith(f"{path}: ") else msg


def _downscale(img: np.ndarray) -> tuple[np.ndarray, float]:
    s = min(1.0, MAX_SIDE / max(img.shape[:2]))
    if s == 1.0:
        return img, 1.0
    size = (round(img.shape[1] * s), round(img.shape[0] * s))
    return cv2.resize(img, size, interpolation=cv2.INTER_AREA), s


