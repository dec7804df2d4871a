"""``recon video`` over many videos: each video (or frame folder) one task of a
``recon.executor`` (this process, local worker processes or a Ray cluster), written by
``recon.video.run.video`` into ``<out>/<name>/``.

A worker builds its networks once and a fresh keypoint source per video. It reads the video and
writes its folder in place, so on a cluster every node sees the inputs and the output folder at
the same paths (a shared file system); a video's finished batches stay in its folder, so a video
whose worker died continues where it stopped, as does a re-run. ``<out>/videos.json`` lists every
input: done, unchanged (finished earlier from the same file and options) and failed (with why).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from recon.errors import ReconError
from recon.executor import ExecutorConfig, WorkerLost, WorkerSpec, run_job
from recon.export.records import write_json
from recon.pipeline import Reconstructor
from recon.reconstruction import ReconstructorConfig
from recon.run import check_writable
from recon.version import __version__
from recon.video.run import VideoOptions, video, video_config, video_reconstructor, video_source


@dataclass
class VideosSummary:
    done: dict[str, str] = field(default_factory=dict)  # name -> source
    unchanged: dict[str, str] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)  # source -> why
    interrupted: bool = False
    seconds: float = 0.0

    def to_json(self) -> dict:
        return {"recon": __version__, "counts": {k: len(getattr(self, k)) for k in ("done", "unchanged", "failed")},
                "interrupted": self.interrupted, "seconds": round(self.seconds, 1), "done": self.done,
                "unchanged": self.unchanged, "failed": self.failed}

    def line(self) -> str:
        s = f"videos: done {len(self.done)}, unchanged {len(self.unchanged)}, failed {len(self.failed)}"
        return s + (" - interrupted: run the same command again to resume" if self.interrupted else "")


def names(inputs: list[str | Path]) -> dict[str, Path]:
    """Output folder name -> input: the file's stem or the folder's name, numbered where two
    inputs would share one."""
    out: dict[str, Path] = {}
    for p in map(Path, inputs):
        if not p.exists():
            raise ReconError(f"{p}: no such video or frame folder")
        name, n = p.stem if p.is_file() else p.name, 2
        key = name
        while key in out:
            key, n = f"{name}_{n}", n + 1
        out[key] = p
    return out


class VideoWorker:
    """Runs ``video`` on (input, output folder) tasks; the Reconstructor is built once, its
    keypoint source made again for every video."""

    def __init__(self, options: VideoOptions, config: ReconstructorConfig, page: bool = True):
        self.options, self.config, self.page = options, video_config(config), page
        self.rec: Reconstructor | None = None

    def __call__(self, task: tuple[str, str]) -> dict:
        path, out = task
        if self.rec is None:
            self.rec = video_reconstructor(self.config, self.options.max_people)
        else:
            source = video_source(self.config, self.options.max_people)
            if source is not None:
                self.rec.source.close()
                self.rec.source = source
        lines: list[str] = []
        t0 = time.perf_counter()
        try:
            r = video(path, out, self.options, reconstructor=self.rec, progress=False, log=lines.append,
                      page=self.page)
        except ReconError as e:
            return {"status": "failed", "message": str(e), "log": lines}
        return {"status": "unchanged" if r.unchanged else "done", "tracks": len(r.tracks),
                "frames": len(r.frames.index), "seconds": round(time.perf_counter() - t0, 1), "log": lines}


def videos(inputs: list[str | Path], out: str | Path, options: VideoOptions | None = None,
           config: ReconstructorConfig | None = None, executor: ExecutorConfig | None = None, progress: bool = True,
           log=print, page: bool = True) -> VideosSummary:
    """Every input video into ``<out>/<name>/`` (module doc), each with its results page (``page``)."""
    options = options or VideoOptions()
    out = Path(out)
    check_writable(out)
    todo = names(inputs)
    keys = list(todo)
    tasks = [(str(p.resolve()), str((out / key).resolve())) for key, p in todo.items()]  # any worker's cwd
    summary, t0 = VideosSummary(), time.time()

    def finished(i: int, r: dict) -> int:
        key, src = keys[i], str(todo[keys[i]])
        for line in r["log"]:
            log(f"{key}: {line}")
        if r["status"] == "failed":
            summary.failed[src] = r["message"]
            log(f"failed: {src}: {r['message']}")
        else:
            getattr(summary, r["status"])[key] = src
        return 1

    def lost(i: int, why: WorkerLost) -> dict:
        return {"status": "failed", "message": f"worker lost: {why}", "log": []}

    spec = WorkerSpec(VideoWorker, (options, config or ReconstructorConfig(), page))
    try:
        summary.interrupted = not run_job(spec, tasks, finished, lost, executor, None, "recon video", "video",
                                          progress=progress)
    finally:
        summary.seconds = time.time() - t0
        summary.done = dict(sorted(summary.done.items(), key=lambda kv: keys.index(kv[0])))
        write_json(out / "videos.json", summary.to_json())
    log(summary.line())
    return summary
