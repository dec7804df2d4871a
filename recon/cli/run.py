"""``recon run`` (photos -> bodies), ``recon demo`` (the bundled photos), ``recon animate``
(a reconstructed person moved by a mocap clip) and ``recon view`` (an output folder's page)."""
from __future__ import annotations

import argparse

from recon.cli.parsing import (
    COUNT,
    NON_NEGATIVE,
    POSITIVE,
    SEED,
    STEPS,
    Parser,
    add_executor,
    device,
    known,
    number,
    run_by,
)

FOCAL = number(float, 0.05, 20.0)  # in units of the longer image side: a fisheye to a long telephoto
TIGHTNESS = number(float, -1.0, 1.0)


INFLUENCES_HELP = ("the .glb files keep every joint influence of a vertex (default: the 4 strongest, renormalised, "
                   "which three.js, Unity and most engines read)")
GARMENT_MODEL_HELP = ("with an outfit: pbns (PBNS, NCS for motions), taylor (example-based: the body-shape dimension "
                      "from drapes on many bodies; `recon garment train --model taylor` builds its database) or "
                      "deepsd (any outfit mesh, no training; what a mesh without PBNS weights gets)")

PAGE_HELP = "no results page (index.html: the folder's results in a browser, offline; see `recon view`)"


def add_run(p: Parser) -> None:
    models = tuple(known("recon.people.mediapipe:MODELS"))
    opts = "recon.run:RunOptions"
    cfg = "recon.reconstruction:ReconstructorConfig"
    p.set_defaults(func=run_by("run:run_images"))
    p.add_argument("inputs", nargs="*", help="image files or folders (none: the bundled example photos)")
    p.add_argument("--out", required=True, help="output folder (one subfolder per image; an interrupted run resumes)")
    p.add_argument("--force", action="store_true",
                   help="make every image again (default: images already done from the same file and options are "
                        "left as they are)")
    p.add_argument("--batch-size", type=COUNT, default=known(opts, "batch_size"),
                   help="images per SMPLR/fit batch (a task of --executor)")
    add_executor(p, 1, "processes reconstructing batches of images, each loading the models once")
    p.add_argument("--device", type=device, default=known(cfg, "device"), help="torch device of the networks")
    p.add_argument("--focal", type=FOCAL, default=None,
                   help="focal length in units of the longer image side (default: the photo's EXIF 35 mm "
                        f"equivalent, else {known(cfg, 'focal_factor')})")
    p.add_argument("--no-overlay", action="store_true", help="skip overlay.png / side.png rendering")
    p.add_argument("--no-page", action="store_true", help=PAGE_HELP)
    p.add_argument("--all-influences", action="store_true", help=INFLUENCES_HELP)
    p.add_argument("--max-people", type=number(int, 1, 50), default=known(opts, "max_people"),
                   help="people per image, the largest first (MediaPipe: found one after the other); above 1 every "
                        "image folder holds person_0/, person_1/, ... and one overlay")
    p.add_argument("--source", choices=known("recon.keypoints:SOURCES"), default=known(cfg, "source"),
                   help="keypoints: MediaPipe + adapter, or our volumetric hourglass alone")
    p.add_argument("--keypoint-model", choices=models, default=known(cfg, "keypoint_model"),
                   help="MediaPipe's landmark model (full: ~half the time, less accurate; without heavy's file: full)")
    p.add_argument("--retry", action=argparse.BooleanOptionalAction, default=known(cfg, "retry"),
                   help="MediaPipe: when it finds nobody, ask again on padded/mirrored views and at a lower "
                        "threshold (more people found, and more phantoms on person-free images)")
    p.add_argument("--guard", action=argparse.BooleanOptionalAction, default=known(cfg, "guard"),
                   help="MediaPipe: refuse answers scored as phantoms (bodies found where there is no person)")
    p.add_argument("--fallback", action=argparse.BooleanOptionalAction, default=known(cfg, "fallback"),
                   help="where MediaPipe finds nobody, our backbone answers when confident (people behind occluders "
                        "in synthetic-like images; on photos it rarely is)")
    p.add_argument("--backbone-weight", type=number(float, 0.0, 1.0), default=known(cfg, "backbone_weight"),
                   help="share of our backbone's keypoints (on MediaPipe's person) where it is confident; 0: "
                        "MediaPipe's alone")
    p.add_argument("--shape-head", action=argparse.BooleanOptionalAction, default=known(cfg, "shape_head"),
                   help="gender and build read from the person's mask (recon.shape) rather than guessed from the "
                        "keypoints by SMPLR")
    p.add_argument("--detect", action=argparse.BooleanOptionalAction, default=known(cfg, "detect"),
                   help="find every person with the person detector (NanoDet, whole image and zoomed tiles) and read "
                        "each on its box; MediaPipe's face-anchored detector only where it finds nobody")
    p.add_argument("--movenet", type=number(float, 0.0, 4.0), default=known(cfg, "movenet"),
                   help="with --detect: weight of MoveNet Thunder's 2D keypoints fused into MediaPipe's on each "
                        "person (0: MediaPipe's alone)")
    p.add_argument("--multipose", action=argparse.BooleanOptionalAction, default=known(cfg, "multipose"),
                   help="with --detect: MoveNet MultiPose's boxes as well, where the detector's give nobody or "
                        "--max-people is above 1 (people it misses or boxes as one in crowds)")
    p.add_argument("--search", action=argparse.BooleanOptionalAction, default=known(cfg, "search"),
                   help="MediaPipe: where its face-anchored detector finds nobody, look for a person without a face "
                        "(back views, people cut by a border, small people)")
    p.add_argument("--gender", choices=("auto", *known("recon.reconstruction:GENDERS")), default=known(cfg, "gender"),
                   help="the body's gender when you know it (auto: read from the person's outline; result.json's "
                        "shape_confidence says how sure)")
    p.add_argument("--height-cm", type=number(float, 50.0, 250.0), default=None,
                   help="the person's standing height when you know it: sets the body's height, and with the focal "
                        "length its distance (a single photo cannot tell scale: docs/pipeline.md)")
    p.add_argument("--lift", choices=known("recon.reconstruction:LIFTS"), default=known(cfg, "lift"),
                   help="SMPLR's 3D J+: the camera-aware lifter on the 2D keypoints, or the source's own 3D")
    p.add_argument("--flip", action=argparse.BooleanOptionalAction, default=None,
                   help="test-time mirror averaging of the keypoints (unset: on for MediaPipe, off for the backbone)")
    p.add_argument("--refine-steps", type=STEPS, default=known("recon.fit:FitConfig.steps"),
                   help="steps fitting the body to the keypoints after SMPLR (0: off)")
    p.add_argument("--silhouette", type=NON_NEGATIVE, default=known("recon.fit:FitConfig.silhouette"),
                   help="weight of the person mask in that fit, which then also fits the body shape "
                        "(0: keypoints only)")
    p.add_argument("--outfit", default=None, help="dress the bodies: a trained outfit (presets: "
                   f"{', '.join(known('recon.garment.templates:PRESETS'))}; or your own, `recon garment train`) or "
                   "any garment mesh (.obj, .ply, "
                   ".glb; body frame, metres), animated by DeePSD without training")
    p.add_argument("--tightness", type=TIGHTNESS, nargs=2, default=None, metavar=("WEIGHT", "HEIGHT"),
                   help="with --outfit: looser (> 0) or tighter (< 0), offsets of the body's weight and height "
                        f"phenotypes (trained range {known('recon.garment.resize:TIGHTNESS_RANGE')}; needs a resizer)")
    p.add_argument("--garment-model", choices=known("recon.garment.dress:GARMENT_MODELS"), default="pbns",
                   help=GARMENT_MODEL_HELP)


def add_animate(p: Parser) -> None:
    p.set_defaults(func=run_by("run:animate_person"))
    p.add_argument("source", nargs="?", help="a photo (reconstructed first), a `recon run` result folder or a "
                                             "`recon video` track folder")
    p.add_argument("--motion", help="a .bvh (CMU, Daz, Mixamo or recon's own skeleton), an .amc, or a shipped "
                                    "clip's name (--list-motions)")
    p.add_argument("--asf", default=None, help="the skeleton of an .amc (default: the one .asf beside it)")
    p.add_argument("--out", help="output folder: animated.glb, animated.mp4 (or .gif), animation.json")
    p.add_argument("--outfit", default=None, help="dress the body (default: the outfit `recon run` used, if any)")
    p.add_argument("--tightness", type=TIGHTNESS, nargs=2, default=None, metavar=("WEIGHT", "HEIGHT"),
                   help="with an outfit that has a resizer: looser (> 0) or tighter (< 0)")
    p.add_argument("--garment-model", choices=known("recon.garment.dress:GARMENT_MODELS"), default=None,
                   help=GARMENT_MODEL_HELP + "; default: the one `recon run` used")
    p.add_argument("--seconds", type=POSITIVE, default=None, help="only the clip's first seconds")
    p.add_argument("--dynamics", action=argparse.BooleanOptionalAction, default=None,
                   help="cloth dynamics (NCS: swings, lags, settles) or quasi-static cloth (PBNS); "
                        "default: dynamic where the outfit has NCS weights")
    p.add_argument("--render", choices=("mp4", "gif", "none"), default="mp4",
                   help="the video (GIF where OpenCV has no MP4 encoder)")
    p.add_argument("--list-motions", action="store_true", help="list the shipped clips and stop")
    p.add_argument("--no-page", action="store_true", help=PAGE_HELP)
    p.add_argument("--all-influences", action="store_true", help=INFLUENCES_HELP)


def add_demo(p: Parser) -> None:
    p.set_defaults(func=run_by("run:demo"))
    p.add_argument("--out", default="out/demo")
    p.add_argument("--seed", type=SEED, default=0)
    p.add_argument("--outfit", default="tshirt-trousers", help="outfit of the dressed renders (if trained)")


def add_view(p: Parser) -> None:
    p.set_defaults(func=run_by("run:view"))
    p.add_argument("folder", help="an output folder of recon run, video, animate or demo (or its index.html)")
    p.add_argument("--rebuild", action="store_true", help="write the page again first (else only when missing)")
    p.add_argument("--no-open", action="store_true", help="print the page's path without opening a browser")


ADD = {"run": add_run, "animate": add_animate, "demo": add_demo, "view": add_view}

