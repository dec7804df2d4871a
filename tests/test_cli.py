"""The command line: model facts, pose statistics and the demo (needs offscreen GL)."""
import json

import trimesh

from recon.cli import main


def test_body_info(capsys):
    assert main(["body", "info"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["joints"][0] == "pelvis" and len(info["landmarks"]) == 18
    assert 1.4 < info["height_m"] < 2.1


def test_body_export_is_the_rest_body_garments_are_modelled_on(body, tmp_path):
    import numpy as np

    from recon.garment.templates import RestBody

    assert main(["body", "export", "--out", str(tmp_path / "rest.obj")]) == 0
    m = trimesh.load(tmp_path / "rest.obj", process=False)
    assert np.abs(m.vertices - RestBody(body).v).max() < 1e-6 and len(m.faces) == len(body.faces)


def test_poses_stats(capsys, mocap):
    assert main(["poses", "stats"]) == 0
    stats = json.loads(capsys.readouterr().out)
    assert stats["train"]["frames"] > stats["test"]["frames"] > 0


def test_demo_writes_png_obj_glb(tmp_path, body, mocap):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    import cv2

    img = cv2.imread(str(tmp_path / "bodies.png"))
    assert img is not None and img.shape[0] > 100
    assert (img < 250).mean() > 0.02  # something was drawn on the white background
    assert cv2.imread(str(tmp_path / "smplr.png")) is not None
    mesh = trimesh.load(tmp_path / "body0.glb", force="mesh")
    assert len(mesh.vertices) > 1000
    assert not list(tmp_path.glob(".*"))  # no temp files left behind


def test_bad_model_is_a_clean_error(capsys):
    assert main(["body", "info", "--model", "nope.fbx"]) == 2
    assert "unknown body model" in capsys.readouterr().err


def test_eval_rejects_unknown_benchmark(capsys):
    assert main(["eval", "--bench", "nope", "--method", "mean"]) == 2
    assert "unknown benchmark" in capsys.readouterr().err
