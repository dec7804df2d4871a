"""The folder layout is the architecture: stages in order, no module importing from a later
stage, no import cycle, imports at the top, runtime garment code free of training/evaluation."""
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
    ("recon.garment",),  # before synth: the other domain's and the training generator's clothes
    ("recon.smplr",),
    ("recon.synth",),
    ("recon.backbone",),
    ("recon.keypoints",),
    ("recon.shape",),
    ("recon.fit",),
    ("recon.pipeline",),
    ("recon.viz",),
    ("recon.bench",),
    ("recon.run",),
    ("recon.animate", "recon.authoring", "recon.sampling"),
    ("recon.video",),
    ("recon.demo",),
    ("recon.cli",),
]
GARMENT_RUNTIME = ("templates", "mesh", "pbns", "ncs", "resize", "dress", "collide", "gltf", "store", "deepsd")


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def stage(module: str) -> int:
    for i, names in enumerate(STAGES):
        if any(module == n or module.startswith(n + ".") for n in names):
            return i
    raise AssertionError(f"{module} belongs to no stage: add it to STAGES")


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


def test_runtime_garment_modules_import_no_training_or_evaluation():
    for name in GARMENT_RUNTIME:
        module = f"recon.garment.{name}"
        for imported, line, _ in imports(MODULES[module]):
            later = ("recon.garment.pbns_train", "recon.garment.pbns_eval", "recon.garment.ncs_",
                     "recon.garment.reference", "recon.garment.integrate")
            assert not imported.startswith(later), f"{module}:{line} imports {imported}"


def test_the_package_facade_exports_what_the_readme_uses():
    assert recon.Reconstructor.__module__ == "recon.pipeline"
    assert recon.SMPLR.__name__ == "SMPLR" and callable(recon.load_image)
    with pytest.raises(AttributeError):
        recon.NoSuchThing  # noqa: B018
