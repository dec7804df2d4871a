"""``recon run``: reconstruct every image of files/folders into an output folder.

Per image ``<out>/<key>/`` (``key``: the path relative to the given folder, without its suffix;
``recon.io.scan_inputs``): ``result.json`` (2D/3D joints and landmarks, pose, shape, camera,
confidence, what it was made from), ``body.obj`` (mesh in the camera frame), ``body.glb``
(rigged: skeleton and skinned body in the photo's pose, in the view frame, with the photo's
camera), ``pose.bvh`` (the pose on the body's skeleton, one frame), ``overlay.png`` (mesh over the
photo) and ``side.png`` (side view); with an outfit also ``outfit.obj`` and ``dressed.glb``.
With ``max_people`` > 1 every image folder holds ``person_0/``, ``person_1/``, ... (each as above,
the largest person first, however many were found), one ``overlay.png`` and ``people.json``.

An image folder is written in a staging folder and moved into place whole, so a folder is either
complete or absent (Ctrl-C, kill -9, a full disk). A complete folder made from the same file bytes,
options and recon version is left as it is (``unchanged``); otherwise it is made again (``--force``:
always). ``<out>/summary.json`` lists every file seen: done, unchanged, no person found, skipped
(not an image or unreadable, with the reason) and failed (an error while reconstructing or writing).
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import time
import uuid
from dataclasses import dataclass, field, replace
from pathlib import Path

from recon.errors import ReconError
from recon.executor import ExecutorConfig, WorkerLost, WorkerSpec, run_job
from recon.export.records import write_json
from recon.io import file_digest, scan_inputs
from recon.page import try_write_page
from recon.pipeline import Reconstructor
from recon.reconstruction import ReconstructorConfig
from recon.run.worker import Job, Outcome, RunOptions, RunWorker, dresser_for
from recon.version import __version__

STAGING = ".recon-staging"  # under the output folder: image folders being written


@dataclass
class RunSummary:
    done: list[str] = field(default_factory=list)  # keys made by this run
    unchanged: list[str] = field(default_factory=list)  # keys an earlier run made from the same file and options
    no_person: dict[str, str] = field(default_factory=dict)  # key -> source: nobody found in the image
    skipped: dict[str, str] = field(default_factory=dict)  # path -> why it is not an image recon can read
    failed: dict[str, str] = field(default_factory=dict)  # path -> error while reconstructing or writing
    interrupted: bool = False
    seconds: float = 0.0

    def to_json(self) -> dict:
        counts = {k: len(getattr(self, k)) for k in ("done", "unchanged", "no_person", "skipped", "failed")}
        return {"recon": __version__, "counts": counts, "interrupted": self.interrupted,
                "seconds": round(self.seconds, 1), "done": self.done, "unchanged": self.unchanged,
                "no_person": self.no_person, "skipped": self.skipped, "failed": self.failed}

    def line(self) -> str:
        s = (f"done {len(self.done)}, unchanged {len(self.unchanged)}, no person found {len(self.no_person)}, "
             f"skipped {len(self.skipped)} (not images or unreadable), failed {len(self.failed)}")
        return s + (" - interrupted: run the same command again to resume" if self.interrupted else "")


def check_writable(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=out, prefix=".write-test-")
        os.close(fd)
        os.unlink(tmp)
    except OSError as e:
        raise ReconError(f"output folder {out} is not writable: {e.strerror or e}") from e


def made_from(digest: str, options: RunOptions, config: ReconstructorConfig) -> dict:
    """What a result is made from: the input's bytes, the options and config, recon's version."""
    return {"recon": __version__, "input_sha256": digest, "options": options.to_json(),
            "reconstructor": config.to_json()}


def recorded(folder: Path) -> dict | None:
    """The ``made_from`` of a complete image folder (result.json or people.json), else None."""
    for name in ("result.json", "people.json"):
        try:
            return json.loads((folder / name).read_text()).get("made_from", {})
        except (OSError, ValueError):
            continue
    return None


def run(inputs: list[str | Path], out: str | Path, options: RunOptions | None = None,
        config: ReconstructorConfig | None = None, reconstructor: Reconstructor | None = None,
        progress: bool = True, log=print, executor: ExecutorConfig | None = None, page: bool = True) -> RunSummary:
    """Reconstruct every image of ``inputs`` into ``out`` (see the module doc). ``config``: the
    reconstruction (default ``recon run``'s); ``reconstructor``: one already built (its config is
    used; this process only), else one is built when the first image needs it. ``executor``:
    where the batches of ``options.batch_size`` images run (default this process); the batches,
    and so every output, are the same for any executor and number of workers. ``page``: write the
    folder's results page (``index.html``, recon.page) at the end, also of an interrupted run."""
    options = options or RunOptions()
    executor = executor or ExecutorConfig()
    if options.max_people < 1 or options.batch_size < 1:
        raise ReconError("max_people and batch_size must be at least 1")
    if reconstructor is not None and not executor.in_process:
        raise ReconError("a Reconstructor object runs in this process only: pass its config for other executors")
    config = reconstructor.config if reconstructor is not None else (config or ReconstructorConfig()).as_installed()
    out = Path(out)
    dresser = dresser_for(options)
    check_writable(out)
    staging = _staging(out)
    scan = scan_inputs(inputs)
    summary, t0 = RunSummary(skipped=dict(scan.skipped)), time.time()
    for path, reason in scan.skipped.items():
        log(f"skipped: {path}: {reason}")
    todo: list[Job] = []
    for item in scan.files:
        try:
            digest = file_digest(item.path)
        except OSError as e:
            summary.skipped[str(item.path)] = f"cannot read ({e.strerror or e})"
            log(f"skipped: {item.path}: cannot read ({e.strerror or e})")
            continue
        stamp = made_from(digest, options, config)
        if not options.force and recorded(out / item.key) == stamp:
            summary.unchanged.append(item.key)
        else:
            todo.append(Job(str(item.path), item.key, stamp))
    if not scan.files and not scan.skipped:
        log(f"no files found in {', '.join(map(str, inputs))}")
    batches = [todo[b:b + options.batch_size] for b in range(0, len(todo), options.batch_size)]
    spec = WorkerSpec(RunWorker, (options, config),
                      {"reconstructor": reconstructor, "dresser": dresser} if executor.in_process else {})

    def finished(b: int, outcomes: list[Outcome]) -> int:
        for o in outcomes:
            record(summary, out, staging, o, log)
        return len(outcomes)

    def lost(b: int, why: WorkerLost) -> list[Outcome]:
        return [Outcome(j.path, j.key, "failed", f"worker lost: {why}") for j in batches[b]]

    try:
        summary.interrupted = not run_job(spec, batches, finished, lost, executor,
                                          _with_bytes if executor.remote else None, "recon run", "img", len(todo),
                                          progress)
    finally:
        order = {j.key: n for n, j in enumerate(todo)}
        summary.done.sort(key=order.__getitem__)  # input order, whichever worker finished first
        summary.seconds = time.time() - t0
        shutil.rmtree(staging, ignore_errors=True)
        with contextlib.suppress(OSError):
            staging.parent.rmdir()  # when no other run is writing here
        try:
            write_json(out / "summary.json", summary.to_json())
        except OSError:
            pass
    if page:
        try_write_page(out, log, kind="run")
    log(summary.line())
    return summary


def _with_bytes(batch: list[Job]) -> list[Job]:
    """The batch with each file's bytes, for a worker that may not see this machine's files."""
    jobs = []
    for j in batch:
        try:
            jobs.append(replace(j, data=Path(j.path).read_bytes()))
        except OSError as e:
            jobs.append(replace(j, error=f"cannot read ({e.strerror or e})"))
    return jobs


def record(summary: RunSummary, out: Path, staging: Path, o: Outcome, log) -> None:
    """One image's outcome into the summary; a finished folder written in the staging folder and
    moved into place whole."""
    if o.status == "skipped":
        summary.skipped[o.path] = o.message
        log(f"skipped: {o.path}: {o.message}")
    elif o.status == "no_person":
        summary.no_person[o.key] = o.path
        log(f"no person found: {o.path}")
    elif o.status == "failed":
        summary.failed[o.path] = o.message
        log(f"failed: {o.path}: {o.message}")
    else:
        tmp = staging / uuid.uuid4().hex
        try:
            for name, data in o.files.items():
                (tmp / name).parent.mkdir(parents=True, exist_ok=True)
                (tmp / name).write_bytes(data)
            _move_into_place(tmp, out / o.key, staging)
            summary.done.append(o.key)
        except OSError as e:
            summary.failed[o.path] = f"cannot write outputs ({e.strerror or e})"
            log(f"failed: {o.path}: cannot write outputs ({e.strerror or e})")
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


def _staging(out: Path) -> Path:
    """This run's staging folder; those of runs that are no longer alive are removed."""
    root = out / STAGING
    if root.is_dir():
        for d in root.iterdir():
            pid = d.name.split("-")[0]
            if not (pid.isdigit() and _alive(int(pid))):
                shutil.rmtree(d, ignore_errors=True)
    path = root / f"{os.getpid()}-{uuid.uuid4().hex[:8]}"
    path.mkdir(parents=True)
    return path


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return False  # an earlier run of this process (the API called twice) is over
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _move_into_place(tmp: Path, dst: Path, staging: Path) -> None:
    """Replace ``dst`` by the finished folder ``tmp``: two renames on one file system."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.exists() or dst.is_symlink():
        old = staging / f"old-{uuid.uuid4().hex}"
        os.rename(dst, old)
        os.rename(tmp, dst)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.rename(tmp, dst)


