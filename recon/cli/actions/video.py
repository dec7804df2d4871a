"""The actions of ``recon video``: a video (or a folder of frames) -> one motion per person (recon.video)."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from recon.cli.parsing import executor_args
from recon.executor import ExecutorConfig
from recon.reconstruction import ReconstructorConfig
from recon.video import FrameRange, SmoothConfig, VideoOptions, video
from recon.video.many import videos


def run_video(args) -> int:
    config = ReconstructorConfig(keypoint_model=args.keypoint_model, backbone_weight=args.backbone_weight,
                                 **({} if args.focal is None else {"focal_factor": args.focal}))
    frames = FrameRange(start=args.start, end=args.end, every=args.every, fps=args.fps)
    smooth = replace(SmoothConfig(), steps=args.smooth_steps, contact_from=args.planted_from)
    options = VideoOptions(frames=frames, max_people=args.max_people, smooth=smooth, outfit=args.outfit,
                           tightness=args.tightness, overlay=not args.no_overlay, batch=args.batch, force=args.force,
                           static_camera=args.static_camera, all_influences=args.all_influences)
    executor = ExecutorConfig(**executor_args(args))
    if len(args.inputs) > 1:
        s = videos(args.inputs, Path(args.out), options, config, executor, page=not args.no_page)
        return 130 if s.interrupted else (1 if s.failed else 0)
    if not executor.in_process:
        print("one video runs in this process (its frames follow each other); --executor spreads several videos")
    try:
        video(args.inputs[0], Path(args.out), options, config, page=not args.no_page)
    except KeyboardInterrupt:
        print(f"interrupted: run the same command again to continue from the last finished batch ({args.out})")
        return 130
    return 0

