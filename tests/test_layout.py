"""The folder layout is the architecture (docs/architecture.md): stages in order, no module
importing from a later stage, no import cycle, imports at the top, runtime garment code and the
image pipeline free of data, training and evaluation code.

A photo's path: people -> keypoints (MediaPipe + adapter, or the backbone) -> smplr -> shape ->
fit -> pipeline -> garment (Dresser) -> export -> page / run. ``STAGES`` orders the folders so
that each imports only what comes before it: foundations (errors, paths, executor, ...), the body,
geometry, drawing and file formats, then the people, the models with their training data
(garment, smplr, synth, backbone), the rest of the path, and the commands."""
import ast
from pathlib import Path

import pytest

import recon

ROOT = Path(__file__).resolve().parent.parent / "recon"

# Each stage may import from itself and from the stages above it, never from those below.
STAGES = [
    ("recon.errors", "recon.version", "recon.paths", "recon.kernels", "recon.report", "recon.timing", "recon.training",
     "recon.io", "recon.executor"),
    ("recon.body",),
    ("recon.metrics", "recon.camera"),
    ("recon.poses",),
    ("recon.render",),  # drawing: the synthetic data, the overlays and the page use it
    ("recon.export",),  # every file format written: the commands choose the files, export writes them
    ("recon.people",),  # a photo's path starts here: where every person is (imports no other stage)
    ("recon.garment",),  # before synth: the other domain's and the training generator's clothes
    ("recon.smplr",),
    ("recon.synth",),
    ("recon.backbone",),
    ("recon.keypoints",),
    ("recon.shape",),
    ("recon.fit",),
    ("recon.reconstruction",),  # what the pipeline takes and gives
    ("recon.pipeline",),
    ("recon.viz",),
    ("recon.bench",),
    ("recon.page",),  # an output folder's results page: what run, video and animate write last
    ("recon.run",),
    ("recon.animate", "recon.garment.author.command", "recon.garment.gcvae.command"),
    ("recon.video",),
    ("recon.demo",),
    ("recon.cli",),
]
# recon.garment: a core, and a district per model family with the same rooms
GARMENT_FAMILIES = ("pbns", "ncs", "deepsd", "gcvae", "taylor", "author")
ROOMS = {"model": "inference", "sample": "inference", "garment_model": "inference: the family's GarmentModel",
         "data": "training data", "config": "training settings",
         "losses": "training losses", "train": "training", "eval": "evaluation",
         "reference_eval": "evaluation against the reference simulator", "command": "a CLI command",
         "curves": "evaluation curves and checks beside a family's table"}
# the drape solver (drape, on integrate's minimiser) runs at inference too: it continues the Taylor
# model's cloth on a photo
GARMENT_CORE_RUNTIME = ("templates", "outfits", "mesh", "store", "family", "dress", "resize", "collide", "losses",
                        "metrics", "morph", "self_intersection", "drape", "integrate")
GARMENT_CORE_TRAINING = ("data", "reference")
INFERENCE_ROOMS = ("model", "sample", "garment_model")
# a family uses another's inference rooms only; author's data is NCS's teacher run on its own parameters
CROSS_FAMILY = {("author", "ncs.data"), ("author", "ncs.config")}


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def stage(module: str) -> int:
    """The stage of the longest entry of STAGES that names the module or a package above it."""
    found = [(len(n), i) for i, names in enumerate(STAGES) for n in names if module == n or module.startswith(n + ".")]
    assert found, f"{module} belongs to no stage: add it to STAGES"
    return max(found)[1]


def imports(path: Path) -> list[tuple[str, int, bool]]:
    """(imported recon module, line, at module top) for every import of a recon module."""
    tree = ast.parse(path.read_text())
    top = {id(n) for n in tree.body}
    found = []
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            # "from recon.garment import store" imports the submodule recon.garment.store
            names = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in MODULES else node.module
                     for a in node.names]
        for name in names:
            if name == "recon" or name.startswith("recon."):
                found.append((name, node.lineno, id(node) in top))
    return found


def test_every_module_belongs_to_a_stage():
    for m in MODULES:
        if m != "recon":
            stage(m)


@pytest.mark.parametrize("module", [m for m in MODULES if m != "recon"])
def test_no_import_from_a_later_stage_and_imports_at_the_top(module):
    for name, line, at_top in imports(MODULES[module]):
        assert at_top, f"{module}:{line} imports {name} inside a function"
        assert stage(name) <= stage(module), f"{module}:{line} imports {name}, a later stage"


def test_finding_people_needs_no_other_stage():
    """The path's first step: a detector or MediaPipe's own answers, nothing of bodies or models."""
    for m, p in MODULES.items():
        if m.startswith("recon.people"):
            for name, line, _ in imports(p):
                assert name.startswith("recon.people") or stage(name) == 0, f"{m}:{line} imports {name}"


def test_the_module_graph_has_no_cycle():
    graph = {m: {n for n, _, _ in imports(p) if n in MODULES and n != m} for m, p in MODULES.items()}
    # a package's __init__ runs before its submodules: importing recon.x.y also imports recon.x
    state: dict[str, int] = {}

    def visit(m: str, path: list[str]) -> None:
        if state.get(m) == 2:
            return
        assert state.get(m) != 1, "import cycle: " + " -> ".join(path + [m])
        state[m] = 1
        for n in sorted(graph[m]):
            visit(n, path + [m])
        state[m] = 2

    for m in graph:
        visit(m, [])


def garment_modules() -> dict[str, str]:
    """Every module of recon.garment as 'core.<name>' or '<family>.<room>'."""
    out = {}
    for m in MODULES:
        parts = m.split(".")
        if parts[:2] != ["recon", "garment"] or len(parts) == 2 or parts[-1] == "garment":
            continue
        if len(parts) == 3:
            out[m] = f"{parts[2]}.__init__" if parts[2] in GARMENT_FAMILIES else f"core.{parts[2]}"
        else:
            out[m] = ".".join(parts[2:])
    return out


def test_garment_is_a_core_and_one_district_per_family_with_the_same_rooms():
    where = garment_modules()
    families = {w.split(".")[0] for w in where.values() if not w.startswith("core.")}
    assert families == set(GARMENT_FAMILIES)
    for module, w in where.items():
        family, room = w.split(".")
        if family == "core":
            assert room in GARMENT_CORE_RUNTIME + GARMENT_CORE_TRAINING, f"{module}: a core module no list names"
        else:
            assert room in ROOMS or room == "__init__", f"{module}: rooms are {', '.join(ROOMS)}"
            if room != "__init__":
                assert family + ".model" in where.values(), f"{family} has no model.py"


def test_inference_never_imports_training_or_evaluation():
    where = garment_modules()
    core = {f"core.{n}" for n in GARMENT_CORE_RUNTIME}

    def inference(w: str) -> bool:
        return w.split(".")[1] in INFERENCE_ROOMS or w in core

    runtime = {m for m, w in where.items() if inference(w)}
    assert "recon.garment.dress" in runtime and "recon.garment.pbns.model" in runtime
    for module in sorted(runtime):
        for imported, line, _ in imports(MODULES[module]):
            w = where.get(imported, "")
            assert not w or inference(w), \
                f"{module}:{line} imports {imported} ({ROOMS.get(w.split('.')[1], 'core training')})"


def test_the_image_pipeline_imports_no_data_training_or_evaluation_code():
    """``recon.pipeline`` and all it imports, module by module: no synthetic-data generator, no
    trainer, training data, calibration, benchmark or evaluation (what a photo's inference runs
    is what a user installs it for)."""
    closure, todo = set(), ["recon.pipeline"]
    while todo:
        module = todo.pop()
        if module in closure or module not in MODULES:
            continue
        closure.add(module)
        todo += [imported for imported, _, _ in imports(MODULES[module])]
    offline = ("train", "data", "dataset", "calibrate", "eval", "reference_eval", "reference")
    found = sorted(m for m in closure if m.startswith(("recon.synth", "recon.training", "recon.bench"))
                   or m.rsplit(".", 1)[-1] in offline)
    assert "recon.keypoints.sources" in closure and "recon.backbone.search" in closure
    assert not found, f"recon.pipeline imports {found}"


# outside recon.garment (whose rooms say it), a module is offline by its name or its package
OFFLINE_NAMES = ("train", "data", "dataset", "crops", "calibrate", "recipe", "eval", "evaluate", "reference",
                 "reference_eval", "curves")
OFFLINE_PACKAGES = ("recon.synth", "recon.training", "recon.bench")
# commands: they run training and evaluation on request
COMMANDS = ("recon.cli", "recon.demo", "recon.garment.author.command", "recon.garment.gcvae.command")


def offline(module: str) -> bool:
    """Training, its data, calibration or evaluation code."""
    if module.startswith("recon.garment."):
        w = garment_modules().get(module, "core.")
        family, room = w.split(".")
        return room in GARMENT_CORE_TRAINING if family == "core" else room not in INFERENCE_ROOMS + ("__init__",)
    last = module.rsplit(".", 1)[-1]
    return module.startswith(OFFLINE_PACKAGES) or last in OFFLINE_NAMES or last.endswith("_train")


def test_inference_imports_no_training_data_or_evaluation_code_in_any_package():
    """Every module that is not offline (``offline``) nor a command imports no offline module:
    what a photo, a clip or an animation runs is what a user installs recon for."""
    for module, path in MODULES.items():
        if offline(module) or module.startswith(COMMANDS) or module == "recon":
            continue
        for imported, line, _ in imports(path):
            assert not offline(imported), f"{module}:{line} imports {imported}, training/data/evaluation code"


def test_the_garment_core_imports_no_family():
    """Families register themselves (recon.garment.family); the core knows none of them."""
    where = garment_modules()
    for module, w in where.items():
        if w.startswith("core."):
            for imported, line, _ in imports(MODULES[module]):
                assert where.get(imported, "core.").startswith("core."), f"{module}:{line} imports {imported}"


def test_every_installed_garment_family_loads_under_its_name():
    from recon.garment.family import GarmentModel, family, family_names
    names = family_names()
    assert {"pbns", "taylor", "deepsd"} <= set(names)
    for name in names:
        cls = family(name)
        assert issubclass(cls, GarmentModel) and cls.name == name


def test_a_family_uses_another_family_only_through_its_inference_rooms():
    where = garment_modules()
    for module, w in where.items():
        family = w.split(".")[0]
        if family == "core":
            continue
        for imported, line, _ in imports(MODULES[module]):
            other = where.get(imported, "core.").split(".")
            if other[0] not in ("core", family) and other[1] not in INFERENCE_ROOMS:
                assert (family, ".".join(other)) in CROSS_FAMILY, f"{module}:{line} imports {imported}"


def test_the_package_facade_exports_what_the_readme_uses():
    assert recon.Reconstructor.__module__ == "recon.pipeline"
    assert recon.SMPLR.__name__ == "SMPLR" and callable(recon.load_image)
    with pytest.raises(AttributeError):
        recon.NoSuchThing  # noqa: B018
