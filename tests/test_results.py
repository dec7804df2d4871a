"""Committed results stay tied to the code: each results JSON names a function that recomputes a
small slice of it (``check``), and its Markdown is the rendering of its JSON."""
import json
import math
from pathlib import Path

import pytest

from recon import kernels, report
from recon.bench import runner
from recon.garment import evaluate as garment_eval
from recon.garment import evaluate_ncs
from recon.smplr import evaluate as smplr_eval

RESULTS = Path(__file__).resolve().parent.parent / "eval" / "results"
CHECKED = sorted(p for p in RESULTS.glob("*.json") if "check" in json.loads(p.read_text()))
RENDERERS = {"synth-test": runner.render, "synth-wide-test": runner.render, "smplr_anny": smplr_eval.render,
             "garment-pbns": garment_eval.render_pbns,
             "garment-resize-": garment_eval.render_resize, "garment-reference-": garment_eval.render_reference,
             "garment-ncs": evaluate_ncs.render}
RTOL, ATOL = 1e-3, 1e-6  # float noise (measured: <= 1e-4 relative); a real change moves far more


def differences(expected, actual, path=""):
    """Paths where two JSON-like values differ beyond the tolerance."""
    if isinstance(expected, dict):
        keys = set(expected) | set(actual)
        return [d for k in sorted(keys) for d in (differences(expected.get(k), actual.get(k), f"{path}/{k}")
                                                   if k in expected and k in actual else [f"{path}/{k}: missing"])]
    if isinstance(expected, list):
        if len(expected) != len(actual):
            return [f"{path}: {len(expected)} items != {len(actual)}"]
        pairs = enumerate(zip(expected, actual, strict=True))
        return [d for i, (a, b) in pairs for d in differences(a, b, f"{path}[{i}]")]
    if isinstance(expected, float) or isinstance(actual, float):
        if expected is None or actual is None or not math.isclose(expected, actual, rel_tol=RTOL, abs_tol=ATOL):
            return [f"{path}: {expected} != {actual}"]
        return []
    return [] if expected == actual else [f"{path}: {expected!r} != {actual!r}"]


def test_every_evaluation_result_carries_a_check():
    names = {p.stem for p in CHECKED}
    assert {"synth-test", "synth-wide-test", "smplr_anny", "garment-pbns", "backbone-crop-search"} <= names
    assert {f"garment-{kind}-{o}" for kind in ("resize", "reference") for o in
            ("tshirt-trousers", "top-shorts", "tshirt-skirt", "dress", "jumpsuit")} <= names


@pytest.mark.slow
@pytest.mark.parametrize("path", CHECKED, ids=[p.stem for p in CHECKED])
def test_a_slice_of_each_committed_result_is_what_the_code_computes(path):
    diff = differences(*report.recompute_check(path))
    assert not diff, f"{path.name}: {len(diff)} values differ, e.g. " + "; ".join(diff[:5])


@pytest.mark.parametrize("path", [p for p in CHECKED if any(p.stem.startswith(k) for k in RENDERERS)],
                         ids=lambda p: p.stem)
def test_each_markdown_table_renders_its_json(path):
    render = next(f for k, f in RENDERERS.items() if path.stem.startswith(k))
    assert path.with_suffix(".md").read_text() == render(json.loads(path.read_text())).rstrip("\n") + "\n"


def test_the_comparison_notices_a_changed_number():
    assert differences({"a": {"b": [1.0, 2.0]}}, {"a": {"b": [1.0, 2.0 + 1e-5]}}) == []
    assert differences({"a": {"b": [1.0, 2.0]}}, {"a": {"b": [1.0, 2.01]}}) == ["/a/b[1]: 2.0 != 2.01"]
    assert differences({"a": 1, "c": None}, {"a": 2, "c": None}) == ["/a: 1 != 2"]
    assert differences({"a": 1.0}, {}) == ["/a: missing"]


def test_a_check_holds_values_per_cpu_vendor(tmp_path):
    """AMD and Intel compute some slices apart (recon.kernels): the values recorded for this CPU's
    vendor are the committed ones where a check has them, and ``record_check`` stores them."""
    stem = tmp_path / "r"
    check = {"function": "builtins:dict", "kwargs": {"a": 1.0}, "values": {"a": 2.0}}
    (tmp_path / "r.json").write_text(json.dumps({"rows": [1], "check": check}))
    assert differences(*report.recompute_check(stem)) == ["/a: 2.0 != 1.0"]
    assert report.record_check(stem) == {"a": 1.0}
    data = report.read(stem)
    assert data["rows"] == [1] and data["check"]["values"] == {"a": 2.0}
    assert data["check"]["values_by_cpu"] == {kernels.vendor(): {"a": 1.0}}
    assert differences(*report.recompute_check(stem)) == []
