"""``recon garment``: PBNS and NCS outfits, their resizers, tables and physics references."""
from __future__ import annotations

from recon.cli.parsing import COUNT, NON_NEGATIVE, POSITIVE, SEED, STEPS, Parser, actions, known

MODELS = ("pbns", "ncs", "taylor", "author", "deepsd", "gcvae")


# NCS training flags: name -> (type, help); their defaults are NCSTrainConfig's
NCS_FLAGS = {
    "chunks": (COUNT, "train chunks to integrate"),
    "val_chunks": (COUNT, "val chunks"),
    "physics_steps": (STEPS, "physics-loss steps"),
    "static_weight": (NON_NEGATIVE, "weight of PBNS's loss on the static part in the physics steps"),
    "free_weight": (NON_NEGATIVE, "weight of the collision/edge/pin energies on unsolved motions in the physics steps"),
    "field_lr": (NON_NEGATIVE, "learning rate of D's new rows in the physics steps, 0: the principal fields stay"),
    "steps": (STEPS, "fitting steps"),
    "workers": (COUNT, "processes integrating chunks (taylor: draping)"),
}


def add_garment(p: Parser) -> None:
    taylor = "recon.garment.taylor.config:TaylorBuildConfig"
    pbns = "recon.garment.pbns.train:GarmentTrainConfig"
    reference = "recon.garment.pbns.reference_eval:reference_and_report"
    action = actions(p)
    help_outfit = ("preset names, 'all', or your own garment meshes (.obj, .ply, .glb, ...: body frame, metres, "
                   "+Y up; trained into ~/.cache/recon/garments)")
    help_model = ("pbns: quasi-static (ch. 5); ncs: dynamic (ch. 6), trained from the outfit's PBNS; taylor: the "
                  "example-based model's database (drapes on many bodies at anchor poses); "
                  "author: keyframe authoring (simulations with random fabrics, then the intrinsic-space networks); "
                  "deepsd: one model for any outfit (drapes of generated outfits, then the network; --outfit "
                  "unused); gcvae: the generative garment space (registered generated garments; --outfit unused)")
    a = action("train", "garment:train", "train outfits (unsupervised, physics energies): PBNS, then NCS")
    a.add_argument("--outfit", nargs="+", default=["tshirt-trousers"], help=help_outfit)
    a.add_argument("--model", choices=MODELS, default="pbns", help=help_model)
    variants = {*known("recon.garment.deepsd.train:VARIANTS"), *known("recon.garment.gcvae.train:VARIANTS"), "all"}
    a.add_argument("--variant", choices=sorted(variants), default="ours",
                   help="deepsd / gcvae: the model (ours) or an ablation variant")
    a.add_argument("--train-outfits", type=COUNT, default=None,
                   help="deepsd: generated train outfits "
                        f"(default {known('recon.garment.deepsd.data:DeePSDDataConfig', 'train_outfits')})")
    a.add_argument("--anchors", type=COUNT, default=None,
                   help=f"taylor: anchor poses (default {known(taylor, 'anchors')})")
    a.add_argument("--shapes", type=COUNT, default=None,
                   help=f"taylor: bodies draped at each anchor besides PBNS's "
                        f"(default {known(taylor, 'shapes')})")
    a.add_argument("--pose-examples", type=NON_NEGATIVE, default=None,
                   help=f"taylor: poses draped on PBNS's body alone to correct it, besides the anchors "
                        f"(default {known(taylor, 'pose_examples')}; 0: the anchors only)")
    a.add_argument("--fit-poses", type=NON_NEGATIVE, default=None,
                   help=f"taylor: more poses draped on PBNS's body for its fit alone (not corrections; default "
                        f"{known('recon.garment.taylor.config:PoseFitConfig.poses')})")
    a.add_argument("--train-sets", type=COUNT, nargs="+", default=None,
                   help="author: train parameter sets to simulate and train on, one model each (default "
                        f"{known('recon.garment.author.data:AuthorDataConfig', 'train_sets')}; e.g. 32 143 715 for "
                        "the learning curve: days of simulation, resumable, each count's data starts the next's)")
    a.add_argument("--data-only", action="store_true",
                   help="author: the simulations only (of the largest --train-sets), no training")
    a.add_argument("--epochs", type=COUNT, default=None,
                   help=f"PBNS: default {known(pbns, 'epochs')}")
    a.add_argument("--poses", type=COUNT, default=known(pbns, "poses"))
    for name, (kind, help) in NCS_FLAGS.items():
        a.add_argument("--" + name.replace("_", "-"), type=kind, default=None,
                       help=f"NCS: {help} (default {known('recon.garment.ncs.config:NCSTrainConfig.' + name)})")
    a = action("resize", "garment:resize", "train the body-shape + tightness resizer of trained outfits")
    a.add_argument("--outfit", nargs="+", default=["tshirt-trousers"], help=help_outfit)
    a.add_argument("--epochs", type=COUNT, default=known("recon.garment.resize:ResizeConfig.epochs"))
    a = action("eval", "garment:evaluate", "PBNS (and resizer) tables on held-out poses (and shapes); "
               "--model ncs: skinning, PBNS and NCS on held-out clips and against dynamic simulations")
    a.add_argument("--outfit", nargs="+", default=["tshirt-trousers"], help=help_outfit)
    a.add_argument("--model", choices=MODELS, default="pbns",
                   help="taylor: against drapes of held-out poses x bodies (writes garment-taylor.md); author: "
                        "keyframe propagation on held-out fabrics and clips (garment-author.md); deepsd: held-out "
                        "outfits and the presets against their drapes (garment-deepsd.md); gcvae: held-out garments "
                        "(garment-gcvae.md)")
    a.add_argument("--no-simulation", action="store_true",
                   help="--model ncs / taylor: skip the newton simulations (minutes a clip or pose)")
    a.add_argument("--ncs-weights", nargs="+", default=None,
                   help="--model ncs: NCS files to evaluate instead of the shipped ones (one per outfit)")
    a.add_argument("--update", action="store_true",
                   help="--model ncs / author: keep the other outfits' tables of the existing report")
    a.add_argument("--val", action="store_true",
                   help="--model ncs / author: against the val performers' simulations (what recipes are tuned on)")
    a.add_argument("--no-ablations", action="store_true",
                   help="--model author: skip the ablation tables (7 more networks to train: the model card has "
                        "their time); the previous report's are kept, marked as such")
    a.add_argument("--n", type=COUNT, default=None,
                   help=f"held-out test poses (default {known('recon.garment.pbns.eval:evaluate_and_report.n_poses')}; "
                        f"taylor {known('recon.garment.taylor.eval:evaluate_and_report.poses')})")
    a.add_argument("--out", default=str(known("recon.report:RESULTS")))
    a = action("author", "garment:author_clip",
               "a clip's garment animation from edited keyframes (the intrinsic garment space)")
    a.add_argument("--outfit", default="tshirt-skirt", help="an outfit with an authoring model "
                   "(`recon garment train --model author`)")
    a.add_argument("--motion", required=True, help="a .bvh, an .amc or a shipped clip's name or category "
                   "(`recon animate --list-motions`)")
    a.add_argument("--key", action="append", metavar="FRAME:MESH",
                   help="the outfit as wanted at FRAME (a mesh in the outfit's vertex order, e.g. an --export "
                        "edited in Blender); repeat for more keyframes. None: the default material (NCS)")
    a.add_argument("--export", type=STEPS, nargs="+", metavar="FRAME",
                   help="also write the result at these frames as frame_NNNN.obj (to edit into keyframes)")
    a.add_argument("--loop", action="store_true", help="the motion loops: the garment loops with it")
    a.add_argument("--render", choices=("mp4", "gif", "none"), default="mp4")
    a.add_argument("--max-seconds", type=POSITIVE, default=None, help="only the clip's first seconds")
    a.add_argument("--no-page", action="store_true", help="no results page (index.html)")
    a.add_argument("--out", required=True, help="output folder: authored.glb, authored.mp4, authored-preview.mp4 "
                   "(ours beside the keyframes interpolated), authoring.json, index.html")
    a = action("sample", "garment:sample", "garments drawn from the GCVAE's latent space, dressed by DeePSD")
    a.add_argument("--type", choices=known("recon.garment.gcvae.model:TYPES"), required=True)
    a.add_argument("-n", type=COUNT, default=8, help="how many")
    a.add_argument("--seed", type=SEED, default=0)
    a.add_argument("--no-sheet", action="store_true", help="only the .obj files, no samples.jpg")
    a.add_argument("--out", required=True, help="output folder: sample_NN.obj, samples.jpg, samples.json")
    a = action("reference", "garment:reference", "PBNS against a newton cloth drape (needs newton; minutes a pose)")
    a.add_argument("--outfit", nargs="+", default=["tshirt-trousers"], help="preset names or 'all'")
    a.add_argument("--n", type=COUNT, default=known(reference, "poses"),
                   help="held-out test poses to drape")
    a.add_argument("--frames", type=COUNT, default=known(reference, "frames"),
                   help="frame cap of each drape")
    a.add_argument("--workers", type=COUNT, default=known(reference, "workers"),
                   help="drapes run in parallel processes")
    a.add_argument("--rescore", action="store_true", help="score the current weights against the cached drapes "
                   "instead of simulating (after a retrain that barely moved the skinned start)")
    a.add_argument("--out", default=str(known("recon.report:RESULTS")))


ADD = {"garment": add_garment}

