"""``recon`` command line: one subcommand per action, each with only its own flags. A command's
flags live in ``recon.cli.<command>`` (no torch: every ``--help`` takes a tenth of a second; the
defaults are the library's, from the table recon/cli/values.py that tests/test_cli.py checks) and
what it does in ``recon.cli.actions.<command>``, imported when it runs.

    recon run photos/ --out out/run        reconstruct the people in photos (recon.run)
    recon demo --out out/demo              the bundled photos, bodies and an outfit (recon.demo)
    recon animate photo.jpg --motion walk --out out/anim    a person moved by a mocap clip
    recon video clip.mp4 --out out/clip    the people of a video, one motion each (recon.video)
    recon view out/run                     an output folder's results page in the browser (recon.page)
    recon eval --bench synth-test --method ...              methods on a synthetic benchmark
    recon synth bench NAME | generate --out DIR             render benchmarks / training data
    recon body build-cache | info | export
    recon poses build | stats
    recon smplr train | train-lifter | eval
    recon backbone recipe | train | export | calibrate
    recon keypoints collect | train | eval
    recon shape crops | train | eval
    recon garment train | resize | eval | reference

A flag out of its range is refused before anything runs (exit 2, one line). A user error
(``recon.errors.ReconError``: bad input, a missing file or weights, a missing optional package)
prints one line and exits with 2; anything else is a bug and keeps its traceback. Third-party log
noise (TFLite, absl, OpenGL) is hidden unless ``-v``.
"""
from __future__ import annotations

import importlib
import logging
import os
import sys

from recon import kernels
from recon.cli import parsing
from recon.cli.parsing import COUNT, Parser, formatter
from recon.errors import ReconError

# command -> (module that adds its flags and runs it, one-line help)
COMMANDS = {
    "run": ("recon.cli.run", "reconstruct people in images/folders: JSON, OBJ/GLB, BVH, overlay, side view"),
    "demo": ("recon.cli.run", "the bundled photos through `recon run` (+ contact sheet), body and outfit renders"),
    "view": ("recon.cli.run", "open an output folder's results page (index.html, offline) in the browser"),
    "animate": ("recon.cli.run", "move a reconstructed person (shape, outfit) with a mocap clip: animated .glb + "
                                 "video"),
    "video": ("recon.cli.video", "a video (or frame folder) -> one motion per person: BVH, animated .glb, JSON, "
                                 "overlay video"),
    "eval": ("recon.cli.synth", "run methods on a synthetic benchmark; merge into its JSON + Markdown"),
    "synth": ("recon.cli.synth", "render SURREAL-like synthetic samples or a fixed benchmark"),
    "body": ("recon.cli.body", "the body model: build its cache, print its facts, export the rest body"),
    "poses": ("recon.cli.body", "the retargeted mocap pose set (shipped; rebuildable from the raw clips)"),
    "smplr": ("recon.cli.smplr", "SMPLR (DAE, Omega, Psi) and the lifter: train on generated data, or evaluate"),
    "backbone": ("recon.cli.backbone", "the volumetric hourglass: GPU recipe, train, export, calibrate"),
    "keypoints": ("recon.cli.keypoints", "the MediaPipe -> J+ adapter: collect MediaPipe on synth folders, train"),
    "shape": ("recon.cli.shape", "the shape head (gender and build from the person's mask): crops, train, eval"),
    "garment": ("recon.cli.garment", "PBNS and NCS outfits: train, resize, evaluate, compare with a physics drape"),
}
DESCRIPTION = "recon: 3D humans (pose and body shape) from photos, dressed in animated garments."
QUIET = {"GLOG_minloglevel": "2", "TF_CPP_MIN_LOG_LEVEL": "2"}  # MediaPipe's TFLite and glog warnings


def build_parser(argv: list[str] | None = None) -> Parser:
    """The parser. With ``argv`` only the command it names is built (its module imported); without,
    every command (what the tests and docs checks parse against)."""
    ap = Parser(prog="recon", description=DESCRIPTION, formatter_class=formatter,
                epilog="`recon COMMAND --help` lists a command's actions and flags.")
    ap.add_argument("--threads", type=COUNT, default=None, help="torch threads (default: $RECON_THREADS, else 1)")
    ap.add_argument("-v", "--verbose", action="store_true", help="debug logging, third-party log lines too")
    cmds = ap.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=Parser)
    wanted = set(COMMANDS) if argv is None else {_command(argv)}
    for name, (module, help) in COMMANDS.items():
        p = cmds.add_parser(name, help=help, description=help, formatter_class=formatter)
        if name in wanted:
            importlib.import_module(module).ADD[name](p)
    return ap


def recorded_values() -> dict:
    """Every library value the flags show (``parsing.known``), read from the library itself:
    what recon/cli/values.py must hold (scripts/cli_values.py writes it)."""
    parsing.RECORDING = {}
    try:
        build_parser()
        return parsing.RECORDING
    finally:
        parsing.RECORDING = None


def _command(argv: list[str]) -> str | None:
    """The command named in ``argv`` (the first word that is one), skipping the global flags."""
    return next((a for a in argv if a in COMMANDS), None)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    verbose = "-v" in argv or "--verbose" in argv
    kernels.pin()  # before torch and Mesa load: the same float kernels on every x86-64 machine
    if not verbose:
        for var, value in QUIET.items():
            os.environ.setdefault(var, value)
    args = build_parser(argv).parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("recon").setLevel(logging.DEBUG if verbose else logging.INFO)
    importlib.import_module("torch").set_num_threads(args.threads or int(os.environ.get("RECON_THREADS", "1")))
    try:
        code = args.func(args)
    except ReconError as e:
        print(f"recon: error: {e}", file=sys.stderr)
        return 2
    return code or 0
