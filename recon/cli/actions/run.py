"""The actions of ``recon run`` (photos -> bodies), ``recon demo`` (the bundled photos),
``recon animate`` (a reconstructed person moved by a mocap clip) and ``recon view``."""
from __future__ import annotations

from pathlib import Path

from recon.animate import animate, list_motions
from recon.cli.parsing import executor_args
from recon.demo import body_demo, dressed_gif, example_photos, photo_demo
from recon.errors import MissingFile, ReconError
from recon.executor import ExecutorConfig
from recon.fit import FitConfig
from recon.garment import store
from recon.page import open_in_browser, try_write_page, write_page
from recon.reconstruction import ReconstructorConfig
from recon.run import RunOptions, run


def run_images(args) -> int:
    config = ReconstructorConfig(source=args.source, device=args.device, flip=args.flip, lift=args.lift,
                                 retry=args.retry, guard=args.guard, keypoint_model=args.keypoint_model,
                                 fallback=args.fallback, backbone_weight=args.backbone_weight,
                                 shape_head=args.shape_head, search=args.search, detect=args.detect,
                                 movenet=args.movenet, multipose=args.multipose, gender=args.gender,
                                 height_cm=args.height_cm,
                                 fit=FitConfig(steps=args.refine_steps, silhouette=args.silhouette),
                                 **({} if args.focal is None else {"focal_factor": args.focal}))
    options = RunOptions(outfit=args.outfit, tightness=args.tightness, max_people=args.max_people,
                         overlay=not args.no_overlay, exif_focal=args.focal is None, batch_size=args.batch_size,
                         force=args.force, garment_model=args.garment_model, all_influences=args.all_influences)
    s = run(args.inputs or example_photos(), Path(args.out), options, config,
            executor=ExecutorConfig(**executor_args(args)), page=not args.no_page)
    if s.interrupted:
        return 130
    return 1 if s.failed or not (s.done or s.unchanged or s.no_person) else 0


def animate_person(args) -> int:
    if args.list_motions:
        print(list_motions())
        return 0
    if not args.source or not args.motion or not args.out:
        raise ReconError("recon animate needs a photo or result folder, --motion and --out (or --list-motions)")
    written = animate(args.source, args.motion, args.out, outfit=args.outfit, tightness=args.tightness, asf=args.asf,
                      max_seconds=args.seconds, render=args.render, dynamics=args.dynamics,
                      garment_model=args.garment_model, page=not args.no_page, all_influences=args.all_influences)
    for path in written.values():
        print(path)
    return 0


def demo(args) -> None:
    out = Path(args.out)
    outfit = args.outfit if store.pbns_path(args.outfit).exists() else None
    written = photo_demo(out, outfit) + body_demo(out, seed=args.seed)
    if outfit:
        written.append(dressed_gif(out, outfit))
    if index := try_write_page(out, kind="demo"):
        written.append(index)
    for p in written:
        print(p)


def view(args) -> int:
    """Open an output folder's results page (written first when missing, or with --rebuild)."""
    folder = Path(args.folder)
    if folder.name == "index.html":
        folder = folder.parent
    if not folder.is_dir():
        raise MissingFile(f"{folder}: no such folder")
    index = folder / "index.html"
    if args.rebuild or not index.is_file():
        try:
            write_page(folder)
        except FileNotFoundError as e:
            raise ReconError(str(e)) from None
    print(index.resolve())
    if not args.no_open and not open_in_browser(index):
        print("no browser found here: open the path above in one (it works from the file system, offline)")
    return 0

