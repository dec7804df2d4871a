"""Committed results stay tied to the code: each results JSON names a function that recomputes a
small slice of it (``check``), and its Markdown is the rendering of its JSON."""
import json
import math
from pathlib import Path

import pytest

from recon import report
from recon.bench import runner
from recon.garment.author import eval as author_eval
from recon.garment.deepsd import eval as deepsd_eval
from recon.garment.ncs import eval as ncs_eval
from recon.garment.pbns import eval as pbns_eval
from recon.garment.pbns import reference_eval
from recon.garment.taylor import eval as taylor_eval
from recon.smplr import evaluate as smplr_eval

RESULTS = Path(__file__).resolve().parent.parent / "eval" / "results"
CHECKED = sorted(p for p in RESULTS.glob("*.json") if "check" in json.loads(p.read_text()))
RENDERERS = {"synth-test": runner.render, "synth-wide-test": runner.render, "other-": runner.render,
             "smplr_anny": smplr_eval.render,
             "garment-pbns": pbns_eval.render_pbns,
             "garment-resize-": pbns_eval.render_resize, "garment-reference-": reference_eval.render_reference,
             "garment-ncs": ncs_eval.render, "garment-deepsd": deepsd_eval.render, "garment-taylor": taylor_eval.render}
def differences(expected, actual, path="", rtol=report.CHECK_TOLERANCE["rtol"], atol=report.CHECK_TOLERANCE["atol"]):
    """Paths where two JSON-like values differ beyond the tolerance."""
    if isinstance(expected, dict):
        keys = set(expected) | set(actual)
        return [d for k in sorted(keys) for d in (differences(expected.get(k), actual.get(k), f"{path}/{k}", rtol, atol)
                                                   if k in expected and k in actual else [f"{path}/{k}: missing"])]
    if isinstance(expected, list):
        if len(expected) != len(actual):
            return [f"{path}: {len(expected)} items != {len(actual)}"]
        pairs = enumerate(zip(expected, actual, strict=True))
        return [d for i, (a, b) in pairs for d in differences(a, b, f"{path}[{i}]", rtol, atol)]
    if isinstance(expected, float) or isinstance(actual, float):
        if expected is None or actual is None or not math.isclose(expected, actual, rel_tol=rtol, abs_tol=atol):
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
    expected, actual, tol = report.recompute_check(path)
    diff = differences(expected, actual, **tol)
    assert not diff, f"{path.name}: {len(diff)} values differ beyond {tol}, e.g. " + "; ".join(diff[:5])


@pytest.mark.parametrize("path", [p for p in CHECKED if any(p.stem.startswith(k) for k in RENDERERS)],
                         ids=lambda p: p.stem)
def test_each_markdown_table_renders_its_json(path):
    render = next(f for k, f in RENDERERS.items() if path.stem.startswith(k))
    assert path.with_suffix(".md").read_text() == render(json.loads(path.read_text())).rstrip("\n") + "\n"


# results no CI machine can recompute (their models are built on the user's machine), rendered all the same
UNCHECKED_RENDERERS = {"garment-author": lambda data: author_eval.render(data["outfits"]),
                       "garment-taylor": taylor_eval.render}


@pytest.mark.parametrize("stem", UNCHECKED_RENDERERS)
def test_results_without_a_check_render_their_json_too(stem):
    path = RESULTS / f"{stem}.json"
    want = UNCHECKED_RENDERERS[stem](json.loads(path.read_text())).rstrip("\n") + "\n"
    assert path.with_suffix(".md").read_text() == want


def test_the_comparison_notices_a_changed_number():
    assert differences({"a": {"b": [1.0, 2.0]}}, {"a": {"b": [1.0, 2.0 + 1e-5]}}) == []
    assert differences({"a": {"b": [1.0, 2.0]}}, {"a": {"b": [1.0, 2.01]}}) == ["/a/b[1]: 2.0 != 2.01"]
    assert differences({"a": 1, "c": None}, {"a": 2, "c": None}) == ["/a: 1 != 2"]
    assert differences({"a": 1.0}, {}) == ["/a: missing"]


def test_a_check_says_how_far_its_values_may_move(tmp_path):
    """A check's own tolerance replaces the default; ``record_check`` stores what the code computes."""
    stem = tmp_path / "r"
    check = {"function": "builtins:dict", "kwargs": {"a": 1.0}, "values": {"a": 1.004}, "tolerance": {"rtol": 1e-2}}
    (tmp_path / "r.json").write_text(json.dumps({"rows": [1], "check": check}))
    expected, actual, tol = report.recompute_check(stem)
    assert tol == {"rtol": 1e-2, "atol": report.CHECK_TOLERANCE["atol"]} and differences(expected, actual, **tol) == []
    assert differences(expected, actual) == ["/a: 1.004 != 1.0"]
    assert report.record_check(stem) == {"a": 1.0} and report.read(stem)["check"]["values"] == {"a": 1.0}


def test_checks_leave_out_methods_behind_a_detector():
    """A detection or crop search can flip on another CPU: those methods are benchmarks, not checks."""
    for name in ("synth-test", "synth-wide-test"):
        check = report.read(RESULTS / name)["check"]
        assert check["kwargs"]["methods"] == runner.checked(check["kwargs"]["methods"])
        assert set(check["values"]) == set(check["kwargs"]["methods"])
    assert runner.checked(["mediapipe", "recon-run", "backbone", "backbone-gtcrop", "smplr-gt2d"]) == [
        "backbone-gtcrop", "smplr-gt2d"]
