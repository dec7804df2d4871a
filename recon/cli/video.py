"""``recon video``: a video (or a folder of frames) -> one motion per person (recon.video)."""
from __future__ import annotations

from recon.cli.parsing import COUNT, NON_NEGATIVE, POSITIVE, STEPS, Parser, add_executor, known, number, run_by
from recon.cli.run import FOCAL, INFLUENCES_HELP, PAGE_HELP, TIGHTNESS


def add_video(p: Parser) -> None:
    models = tuple(known("recon.people.mediapipe:MODELS"))
    opts = "recon.video:VideoOptions"
    cfg = "recon.reconstruction:ReconstructorConfig"
    p.set_defaults(func=run_by("video:run_video"))
    p.add_argument("inputs", nargs="+", metavar="input",
                   help="a video file OpenCV reads (mp4, avi, mov, webm, mkv) or a folder of frames; several: each "
                        "into <out>/<name>/, one video a task of --executor, videos.json beside them")
    p.add_argument("--out", required=True, help="output folder: track_<id>/ (motion.bvh, animated.glb, motion.json), "
                                                "overlay.mp4, video.json; a killed run continues")
    add_executor(p, 1, "processes each taking one video at a time (with several videos)")
    p.add_argument("--start", type=NON_NEGATIVE, default=0.0, help="first second")
    p.add_argument("--end", type=POSITIVE, default=None, help="last second (exclusive; default: the end)")
    p.add_argument("--every", type=COUNT, default=1, help="take one frame in every N")
    p.add_argument("--fps", type=POSITIVE, default=None, help="at most this many frames a second")
    p.add_argument("--max-people", type=number(int, 1, 20), default=known(opts, "max_people"),
                   help="people followed; 1 uses MediaPipe's video mode (faster, steadier); more follows each on "
                        "a crop where they were, and searches the frame for newcomers")
    p.add_argument("--focal", type=FOCAL, default=None,
                   help=f"focal length in units of the longer frame side (default {known(cfg, 'focal_factor')})")
    p.add_argument("--keypoint-model", choices=models, default=known(cfg, "keypoint_model"),
                   help="MediaPipe's landmark model (full: about twice as fast, less accurate)")
    p.add_argument("--backbone-weight", type=number(float, 0.0, 1.0), default=known(cfg, "backbone_weight"),
                   help="share of our backbone's keypoints where it is confident (synthetic-like footage; it stops "
                        "asking where it is not); 0: MediaPipe's alone")
    p.add_argument("--static-camera", action="store_true",
                   help="take the camera as still even where it turned (default: a turn of more than "
                        f"{known('recon.video.camera_motion:MOVING_DEGREES')} degrees, measured on the background, "
                        "is taken out of the people's motion; a turn measured on under "
                        f"{round(100 * known('recon.video.camera_motion:MIN_MEASURED'))} %% of the frames is not)")
    p.add_argument("--smooth-steps", type=STEPS, default=known("recon.video:SmoothConfig.steps"),
                   help="iterations of the track optimisation (0: the per-frame estimates, gaps interpolated)")
    p.add_argument("--planted-from", choices=known("recon.video.smooth:CONTACT_FROM"),
                   default=known("recon.video:SmoothConfig.contact_from"),
                   help="which feet the track optimisation pins: where the 2D keypoints stand still and low "
                        "(image), where the learned motion prior says so (prior), or either")
    p.add_argument("--outfit", default=None, help="dress the animated bodies: a trained outfit (presets: "
                   f"{', '.join(known('recon.garment.templates:PRESETS'))}); NCS dynamics where it has them")
    p.add_argument("--tightness", type=TIGHTNESS, nargs=2, default=None, metavar=("WEIGHT", "HEIGHT"),
                   help="with --outfit: looser (> 0) or tighter (< 0) (needs a resizer)")
    p.add_argument("--no-overlay", action="store_true", help="skip overlay.mp4")
    p.add_argument("--no-page", action="store_true", help=PAGE_HELP)
    p.add_argument("--all-influences", action="store_true", help=INFLUENCES_HELP)
    p.add_argument("--batch", type=COUNT, default=known(opts, "batch"), help="frames per stored batch")
    p.add_argument("--force", action="store_true",
                   help="start again (default: a finished folder is left as it is, an unfinished one continues)")


ADD = {"video": add_video}

