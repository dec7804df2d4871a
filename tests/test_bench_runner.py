"""The benchmark runner's other-domain numbers: people found by view and cut, gender on the
extremes, per-image scores and their paired comparison, and `recon run` variants by name."""
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from recon.bench import runner
from recon.bench.methods import METHODS, ReconRun, get_method
from recon.errors import ReconError

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "eval"))
import compare  # noqa: E402


def _row(p1, gender=None):
    r = {"p1": p1, "p2": p1 / 2}
    if gender is not None:
        r["shape_pred"] = np.array([gender, 0.5, 0.5, 0.5, 0.5, 0.5])
    return r


def test_found_by_view_and_cut():
    info = np.array([[10, 0.0], [170, 0.0], [-90, 0.3], [-20, 0.2]], np.float32)
    info = np.concatenate([info, np.zeros((4, 3), np.float32)], 1)
    scores = [_row(0.1), None, _row(0.1), None]
    v = runner.found_by_view(info, scores)
    assert v["front"] == 0.5 and v["back"] == 0.0 and v["side"] == 1.0
    assert v["cut"] == 0.5 and v["whole"] == 0.5


def test_gender_counts_only_the_extremes_on_the_right_side():
    true = np.array([[0.1], [0.9], [0.5], [0.95], [0.05]]) * np.ones((1, 6))
    scores = [_row(0.1, 0.2), _row(0.1, 0.7), _row(0.1, 0.9), _row(0.1, 0.4), None]
    g = runner.gender_extremes(true, scores, 0)
    assert g == {"gender_right_extremes": pytest.approx(2 / 3), "gender_extremes_n": 3}


def test_per_image_numbers_round_trip_for_comparisons(tmp_path):
    a = [_row(0.100), None, _row(0.120), _row(0.080)]
    b = [_row(0.090), _row(0.2), _row(0.110), _row(0.070)]
    for name, rows in (("A", a), ("B", b)):
        path = runner.scores_path(tmp_path, "bench", name)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(runner.per_image(rows)))
    c = compare.compare("bench", "A", "B", tmp_path)
    assert (c["found_a"], c["found_b"], c["both"]) == (0.75, 1.0, 3)
    assert c["p1"]["diff"][0] == pytest.approx(-10.0)  # mm, on the three images both found
    assert c["p1"]["diff"][1] == pytest.approx(-10.0) and c["p1"]["diff"][2] == pytest.approx(-10.0)
    assert "B - A" in compare.describe(c)
    assert runner.scores_path(tmp_path, "b", "recon-run[search=False]").name == "recon-run_search=False_.json"


def test_bootstrap_interval_contains_the_mean():
    x = np.random.default_rng(0).normal(2.0, 1.0, 400)
    m, lo, hi = compare.interval(x, np.random.default_rng(1))
    assert lo < m < hi and lo < 2.0 < hi and hi - lo < 0.5


def test_recon_run_variants_by_name():
    cls = get_method("recon-run[search=False,backbone_weight=0.5,fit_steps=0]")
    assert issubclass(cls, ReconRun) and cls.detects and "search=False" in cls.description
    assert get_method("recon-run") is METHODS["recon-run"]
    with pytest.raises(ReconError, match="no ReconstructorConfig"):
        get_method("recon-run[colour=1]")
    with pytest.raises(ReconError, match="unknown method"):
        get_method("not-a-method")


def test_body_weight_is_the_closed_rest_meshs_volume_and_grows_with_the_weight_phenotype():
    import torch
    import trimesh

    from recon.body import default_body

    body = default_body()
    names = list(body.shape_names)
    mid = np.full(len(names), 0.5, np.float32)
    with torch.no_grad():
        v = body(shape=torch.as_tensor(mid)[None]).rest_vertices[0].numpy()
    mesh = trimesh.Trimesh(v, body.faces.numpy(), process=False)
    assert mesh.is_watertight  # a volume means something only for a closed mesh
    metres, kg = runner.body_size(body, mid)
    assert metres == pytest.approx(float(v[:, 1].max() - v[:, 1].min()))
    assert kg == pytest.approx(abs(mesh.volume) * runner.BODY_DENSITY, rel=1e-4)
    assert 30.0 < kg < 120.0
    light, heavy = mid.copy(), mid.copy()
    light[names.index("weight")], heavy[names.index("weight")] = 0.0, 1.0
    assert runner.body_size(body, light)[1] < kg < runner.body_size(body, heavy)[1]
