"""``recon video``: the people of a video, each one motion (BVH, rigged animated .glb, JSON), and
an overlay video of the clip.

1. Per frame (``recon.video.perframe``): keypoints (MediaPipe in video mode for one person;
   found one after the other for several), the lifter and SMPLR, without the per-image fit; stored
   batch by batch under ``<out>/.work`` so that a killed run continues from its last batch.
2. Tracks (``recon.video.track``): people followed across frames, one id each.
3. Per track (``recon.video.smooth``): one body shape (the median over its frames) and one
   optimisation of the pose and position of every frame; gaps bridged; the ground from the
   planted feet. A camera that turned (``recon.video.camera_motion``, measured on the background
   during the per-frame pass) is taken out: the motion is in the first frame's camera. A turn that
   could not be measured on most of the clip (too little background in view) is not taken out. A
   camera that moved (parallax on the background) has its turn and move fitted together on the
   ground and the far background, at the people's scale (``recon.video.camera_travel``), and both
   are taken out. All tracks are then written in the clip's one world frame, on one ground
   (``recon.video.world``).
4. Outputs (``recon.video.outputs``): ``<out>/track_<id>/`` motion.bvh, animated.glb, motion.json;
   ``<out>/overlay.mp4``; ``<out>/video.json`` last (frames, skipped frames, tracks, timings): it is
   removed before the others are written, so it stands only beside a complete set.

A frame that cannot be decoded is reported and skipped (its track frames are bridged). A finished
output folder made from the same file, options and recon version is left as it is.
"""
from __future__ import annotations

import hashlib
import json
import logging
import shutil
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from recon import camera, paths
from recon.body.base import BodyModel
from recon.errors import ReconError
from recon.export import media
from recon.export.records import write_json
from recon.fit import FitConfig
from recon.garment.dress import Dresser
from recon.io import file_digest
from recon.keypoints.video import MediaPipeVideoSource, PeopleVideoSource
from recon.page import try_write_page
from recon.pipeline import Reconstructor
from recon.reconstruction import ReconstructorConfig
from recon.run import check_writable
from recon.version import __version__
from recon.video.camera_motion import MOVING_DEGREES, CameraRotations, TurnEstimate
from recon.video.camera_travel import travelling_camera
from recon.video.frames import FrameRange, FrameSource
from recon.video.ground import sole_height
from recon.video.outputs import OverlayFrames, WorldMotion, write_portrait, write_track
from recon.video.perframe import Detections, FrameLog, PerFrame, ahead, same_work, stamp
from recon.video.smooth import SmoothConfig
from recon.video.track import Detection, Track, TrackerConfig, track
from recon.video.world import fit_track, one_world

WORK = ".work"
log_ = logging.getLogger(__name__)


@dataclass
class VideoOptions:
    """frames: which frames; max_people: tracks kept (1: MediaPipe's video mode); smooth: the track
    optimisation (``SmoothConfig(steps=0)``: the per-frame estimates, gaps interpolated); tracker:
    how people are followed; outfit / tightness: dress the animated bodies; overlay: write
    overlay.mp4; batch: frames per stored batch; force: start again even if finished;
    static_camera: take the camera as still even where it turned; pipeline: decode and find the
    keypoints of the next batch on a second thread (the same results); all_influences: the .glb files
    keep every joint influence of a vertex (default: the 4 strongest, which engines read)."""

    frames: FrameRange = field(default_factory=FrameRange)
    max_people: int = 1
    smooth: SmoothConfig = field(default_factory=SmoothConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    outfit: str | None = None
    tightness: tuple[float, float] | None = None
    overlay: bool = True
    batch: int = 30
    force: bool = False
    static_camera: bool = False
    pipeline: bool = True
    all_influences: bool = False

    def per_frame_json(self) -> dict:
        """What changes the per-frame pass."""
        return {"frames": asdict(self.frames), "max_people": self.max_people}

    def to_json(self) -> dict:
        d = asdict(self)
        d["tightness"] = None if self.tightness is None else [float(t) for t in self.tightness]
        return {k: v for k, v in d.items() if k not in ("batch", "force", "pipeline")}


@dataclass
class VideoResult:
    out: Path
    tracks: list[WorldMotion]
    frames: FrameLog
    detections: Detections
    fps: float
    seconds: dict
    unchanged: bool = False


def video_config(config: ReconstructorConfig | None = None) -> ReconstructorConfig:
    """The reconstruction of each frame: ``recon run``'s, without its per-image fit (the track
    optimisation replaces it)."""
    return replace(config or ReconstructorConfig(), fit=FitConfig(steps=0)).as_installed()


def input_digest(path: Path) -> str:
    """sha256 of a video's bytes, or of a frame folder's names, sizes and times."""
    if path.is_file():
        return file_digest(path)
    h = hashlib.sha256()
    for p in sorted(path.iterdir()):
        if p.is_file():
            st = p.stat()
            h.update(f"{p.name}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def video(path: str | Path, out: str | Path, options: VideoOptions | None = None,
          config: ReconstructorConfig | None = None, reconstructor: Reconstructor | None = None,
          progress: bool = True, log=print, page: bool = True) -> VideoResult:
    """Reconstruct the people of the video (or frame folder) ``path`` into ``out`` (module doc);
    ``page``: with the folder's results page (``index.html``, recon.page)."""
    options = options or VideoOptions()
    if options.max_people < 1 or options.batch < 1:
        raise ReconError("max_people and batch must be at least 1")
    src = FrameSource(path, options.frames)
    out = Path(out)
    check_writable(out)
    dresser = Dresser(options.outfit) if options.outfit else None
    config = reconstructor.config if reconstructor is not None else video_config(config)
    made_from = stamp(input_digest(Path(path)), options.to_json(), config.to_json(), __version__)
    if not options.force and _finished(out) == json.loads(json.dumps(made_from)):
        log(f"{out}: already made from the same video and options (--force makes it again)")
        if page and not (out / "index.html").is_file():
            try_write_page(out, log, kind="video")
        return VideoResult(out, [], FrameLog([], [], []), Detections.empty(0), 0.0, {}, unchanged=True)
    work = out / WORK
    per_frame_from = stamp(made_from["input"], options.per_frame_json(), config.to_json(), __version__)
    if options.force or not same_work(work, per_frame_from):
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True)
        paths.write_text(work / "made_from.json", json.dumps(per_frame_from, indent=1))
    k = camera.default_intrinsics(*src.size, config.focal_factor)
    fps = _output_fps(src, options.frames)
    seconds, t0 = {}, time.perf_counter()
    rec = reconstructor or video_reconstructor(config, options.max_people)
    bar = tqdm(total=_expected(src), desc="recon video", unit="frame", disable=not progress)
    resumed = []
    turn = CameraRotations(k, fps)  # how the camera turned, from the frames as the per-frame pass reads them

    def on_batch(batch, was_stored, boxes):
        bar.update(len(batch))
        if was_stored:
            resumed.append(len(batch))
        for f, people in zip(batch, boxes, strict=True):
            if f.error:
                log(f"skipped frame {f.index}: {f.error}")
            if f.rgb is not None:
                turn.add(f.rgb, people)
            else:
                turn.hold()
    try:
        per_frame = PerFrame(rec, k, work, options.max_people, options.batch, options.pipeline)
        dets, frames = per_frame.run(src, on_batch)
    finally:
        bar.close()
    if resumed:
        log(f"resumed: {sum(resumed)} frames read back from {work}")
    seconds["per_frame"] = time.perf_counter() - t0
    estimate = turn.result()
    rotations, shifts, travel = estimate.rotations, None, None
    if estimate.travelled and not options.static_camera and len(dets):
        rotations, shifts, _ = travelling_camera(estimate, k, dets.frame, dets.points3d + dets.translation[:, None],
                                                 sole_height(rec.body, torch.tensor(np.median(dets.shape, 0))[None]))
        travel = float(np.linalg.norm(np.diff(camera_centres(rotations, shifts), axis=0), axis=1).sum())
    moving = (estimate.turned or shifts is not None) and not options.static_camera
    note = camera_note(estimate, options.static_camera, travel)
    if estimate.turned or not estimate.known or estimate.travelled:
        log(f"camera: {note} (docs/video.md)")
    t0 = time.perf_counter()
    tracks = track(detections_per_frame(dets, len(frames.index)),
                   replace(options.tracker, max_people=options.max_people))
    motions = one_world([fit_track(rec.body, t, dets, k, src.size, options.smooth, rotations if moving else None,
                               shifts if moving else None) for t in tracks])
    seconds["tracks"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    (out / "video.json").unlink(missing_ok=True)  # present only over a complete set of outputs
    cam = {"K": np.round(k, 3).tolist(), "image_size": list(src.size), "focal_from": "default"}
    track_files = {}
    for m in motions:
        track_files[m.id] = list(write_track(out / f"track_{m.id}", rec.body, m, fps, frames.index, frames.time, cam,
                                             dresser, options.tightness, options.all_influences))
    _write_portraits(out, src, motions, _portrait_frames(tracks, dets), track_files)
    for old in out.glob("track_*"):  # an earlier run's tracks beyond this run's
        if old.is_dir() and old.name not in {f"track_{m.id}" for m in motions}:
            shutil.rmtree(old, ignore_errors=True)
    seconds["outputs"] = time.perf_counter() - t0
    if options.overlay:
        t0 = time.perf_counter()
        _write_overlay(out / "overlay.mp4", src, rec.body, motions, k, fps, progress)
        seconds["overlay"] = time.perf_counter() - t0
    summary = {
        "recon": __version__, "source": str(path), "fps": fps, "source_fps": src.fps, "image_size": list(src.size),
        "frames": len(frames.index), "first_frame": frames.index[0] if frames.index else None,
        "skipped": {str(i): e for i, e in zip(frames.index, frames.error, strict=True) if e},
        "people_found_in": int(len(np.unique(dets.frame))),
        "tracks": [{"id": m.id, "folder": f"track_{m.id}", "first": m.first, "frames": len(m.rotmats),
                    "seen": int(m.seen.sum()), "files": track_files[m.id]} for m in motions],
        "seconds": {k_: round(v, 2) for k_, v in seconds.items()},
        "frames_per_second": round(len(frames.index) / max(sum(seconds.values()), 1e-9), 2),
        "overlay_codec": ("h264" if media.h264_available() else "mpeg4") if options.overlay else None,
        "static_camera": not moving, "camera": note,
        "camera_turned_degrees": round(estimate.degrees, 2) if estimate.known else None,
        "camera_turn_measured": round(estimate.measured_share, 3),
        "camera_travelled": estimate.travelled,
        "camera_travelled_m": None if travel is None else round(travel, 3),
        "camera_parallax": round(float(np.median(estimate.parallax)), 3) if len(estimate.parallax) else None,
        "made_from": made_from,
    }
    write_json(out / "video.json", summary)
    if page:
        try_write_page(out, log, kind="video")
    log(f"{len(frames.index)} frames, {len(motions)} track(s), {summary['frames_per_second']} frames/s -> {out}")
    return VideoResult(out, motions, frames, dets, fps, seconds)


def camera_note(estimate: TurnEstimate, static_camera: bool = False, travel: float | None = None) -> str:
    """What ``recon video`` made of the camera's turn and move, in words (the log, video.json, the
    page); ``travel``: the length of its path where it was measured (m)."""
    note = _turn_note(estimate, static_camera)
    if not estimate.travelled:
        return note
    if static_camera or travel is None:
        return note + "; it also moved (the background shifts with depth): the move stays in the people's paths"
    return note + (f"; it also moved, {travel:.2f} m (from the ground and the far background, at the people's "
                   "scale): turn and move are taken out of the people's motion")


def _turn_note(estimate: TurnEstimate, static_camera: bool) -> str:
    measured = f"measured on {estimate.measured_share:.0%} of the frames"
    if not estimate.known:
        return f"taken as still: its turn was {measured} only (too little background in view)"
    if not estimate.turned:
        return f"still (turned {estimate.degrees:.1f} degrees at most, under {MOVING_DEGREES:g}; {measured})"
    if static_camera:
        return f"turned {estimate.degrees:.1f} degrees ({measured}); --static-camera: the turn stays in the motion"
    return f"turned {estimate.degrees:.1f} degrees ({measured}): the turn is taken out of the people's motion"


def video_reconstructor(config: ReconstructorConfig, max_people: int) -> Reconstructor:
    source = video_source(config, max_people)
    return Reconstructor(config) if source is None else Reconstructor(config, source=source)


def video_source(config: ReconstructorConfig, max_people: int):
    """A fresh keypoint source for one video (MediaPipe's video mode follows one video's frames in
    order), or None where the config's source is not MediaPipe's."""
    if config.source != "mediapipe":
        return None
    if max_people == 1:
        return MediaPipeVideoSource(config.keypoint_model, config.guard, config.backbone_weight)
    return PeopleVideoSource(config.keypoint_model, config.guard, config.backbone_weight, detect=config.detect)


def _finished(out: Path) -> dict | None:
    try:
        return json.loads((out / "video.json").read_text()).get("made_from")
    except (OSError, ValueError):
        return None


def _expected(src: FrameSource) -> int | None:
    if not src.count:
        return None
    r = src.range
    n = src.count - int(round(r.start * src.fps))
    if r.end is not None:
        n = min(n, int(round((r.end - r.start) * src.fps)))
    n = -(-max(n, 0) // r.every)
    if r.fps is not None:
        n = min(n, int(np.ceil((n * r.every / src.fps) * r.fps)))
    return n


def _output_fps(src: FrameSource, r: FrameRange) -> float:
    fps = src.fps / r.every
    return min(fps, r.fps) if r.fps is not None else fps


def detections_per_frame(dets: Detections, frames: int) -> list[list[Detection]]:
    """The tracker's input: per frame position, its people as ``Detection`` s."""
    per_frame: list[list[Detection]] = [[] for _ in range(frames)]
    for n in range(len(dets)):
        f = int(dets.frame[n])
        hist = dets.appearance[n]
        per_frame[f].append(Detection(f, dets.box[n].astype(float), dets.points2d[n].astype(float),
                                      None if np.isnan(hist).any() else hist.astype(np.float32), n,
                                      float(dets.translation[n, 2])))
    return per_frame


def _portrait_frames(tracks: list[Track], dets: Detections) -> list[tuple[int, np.ndarray]]:
    """Per track the frame and box its portrait is cut from: of its detections at least as large
    as its median one (not a person half hidden or far) and no wider for their height than the
    median (not two people walking side by side), the one found with most confidence."""
    out = []
    for t in tracks:
        rows = np.array([d.index for d in t.detections])
        box = dets.box[rows]
        w, h = box[:, 2] - box[:, 0], box[:, 3] - box[:, 1]
        big = np.flatnonzero((w * h >= np.median(w * h)) & (w / np.maximum(h, 1) <= np.median(w / np.maximum(h, 1))))
        big = big if len(big) else np.arange(len(rows))
        best = rows[big[np.argmax(dets.confidence[rows[big]])]]
        out.append((int(dets.frame[best]), dets.box[best].astype(float)))
    return out


def _write_portraits(out: Path, src: FrameSource, motions: list[WorldMotion], chosen: list[tuple[int, np.ndarray]],
                     files: dict[int, list[str]]) -> None:
    """Each track's ``person.jpg`` (``write_portrait``), the clip read once up to the last frame needed."""
    wanted: dict[int, list[tuple[int, np.ndarray]]] = {}
    for m, (position, box) in zip(motions, chosen, strict=True):
        wanted.setdefault(position, []).append((m.id, box))
    if not wanted:
        return
    for position, frame in enumerate(src):
        for track_id, box in wanted.pop(position, []) if frame.rgb is not None else []:
            write_portrait(out / f"track_{track_id}" / "person.jpg", frame.rgb, box)
            files[track_id].append("person.jpg")
        if not wanted or position >= max(wanted):
            break


def camera_centres(rotations: np.ndarray, shifts: np.ndarray) -> np.ndarray:
    """(T, 3) where the camera stood in each frame, in the first frame's camera (-R^T t)."""
    return -np.einsum("tji,tj->ti", rotations, shifts)


def _write_overlay(path: Path, src: FrameSource, body: BodyModel, motions: list[WorldMotion], k, fps: float,
                   progress: bool) -> None:
    h, w = src.size
    draw = OverlayFrames(body, motions, k, (h, w), fps)
    bar = tqdm(total=_expected(src), desc="overlay.mp4", unit="frame", disable=not progress)

    def frames():
        last = np.zeros((h, w, 3), np.uint8)  # an undecodable frame shows the last good one
        for position, frame in enumerate(src):
            last = frame.rgb if frame.rgb is not None else last
            yield draw(last, position)
            bar.update(1)
    try:
        media.write_mp4(path, ahead(frames(), 2), fps, (h, 2 * w), browser=True)  # drawn while encoded
    finally:
        bar.close()
        draw.close()
