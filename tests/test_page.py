"""recon.page: the results page of an output folder (index.html, offline) and its 3D models;
in the slow tier a headless Chromium loads pages, photographs the 3D views and watches an
animation advance."""
import base64
import json
import re
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import roma
import torch
import trimesh

from recon import page as rpage
from recon.cli import main
from recon.export.glb import write_glb
from recon.export.media import write_mp4
from recon.garment.dress import Dresser
from recon.garment.morph import outfit_animation
from recon.page import build, models
from recon.page.chromium import Chromium, find_chromium
from tests.gltf_check import assert_valid, read_glb

needs_chromium = pytest.mark.skipif(find_chromium() is None,
                                    reason="a headless Chromium (bash scripts/setup.sh --tests)")
needs_viewer = pytest.mark.skipif(not rpage.viewer_installed(), reason="model-viewer (bash scripts/setup.sh)")
VIEWER_BG = np.array([0xE9, 0xEA, 0xEE])  # .viewer's background in page.css


def _result(folder: Path, vertices: np.ndarray, faces: np.ndarray, source: Path | None = None, outfit=False):
    folder.mkdir(parents=True, exist_ok=True)
    trimesh.Trimesh(vertices, faces, process=False).export(folder / "body.obj")
    files = ["body.obj", "overlay.png"]
    if outfit:
        trimesh.Trimesh(vertices * 1.05, faces, process=False).export(folder / "outfit.obj")
        files.append("outfit.obj")
    cv2.imwrite(str(folder / "overlay.png"), np.full((40, 30, 3), 90, np.uint8))
    r = {"found_by": "mediapipe", "confidence": 0.8123, "person_score": 0.9, "height_m": 1.71,
         "shape": {"gender": 0.2, "age": 0.5}, "camera": {"K": [[500.0, 0, 20], [0, 500.0, 15], [0, 0, 1]],
                                                          "focal_from": "exif"},
         "source": str(source) if source else "x.jpg", "files": files,
         "outfit": {"name": "tshirt-trousers"} if outfit else None}
    (folder / "result.json").write_text(json.dumps(r))


def _run_folder(out: Path, n: int = 2, mesh=None) -> Path:
    """A small `recon run` output: n results (the first dressed), one image without a person, one
    unreadable file and one failure in summary.json."""
    mesh = mesh or trimesh.creation.icosphere(subdivisions=1)
    v = np.asarray(mesh.vertices) * 0.3 + [0.0, 0.0, 3.0]
    for i in range(n):
        _result(out / f"img{i:04d}", v, np.asarray(mesh.faces), outfit=i == 0)
    photo = out.parent / "empty.png"
    cv2.imwrite(str(photo), np.zeros((20, 20, 3), np.uint8))
    summary = {"recon": "x", "counts": {"done": n, "unchanged": 0, "no_person": 1, "skipped": 1, "failed": 1},
               "interrupted": False, "done": [f"img{i:04d}" for i in range(n)], "unchanged": [],
               "no_person": {"empty": str(photo)}, "skipped": {"/data/notes.txt": "not an image"},
               "failed": {"/data/bad.jpg": "cannot write outputs (disk full)"}}
    (out / "summary.json").write_text(json.dumps(summary))
    return out


def _data(out: Path) -> dict:
    text = (out / ".recon-page" / "data.js").read_text()
    return json.loads(text[text.index("=") + 1:].rstrip().rstrip(";"))


def _model(out: Path, mid: str) -> bytes:
    text = (out / ".recon-page" / "models" / f"{mid}.js").read_text()
    m = re.fullmatch(r'RECON_MODEL\("(\w+)","([A-Za-z0-9+/=]*)"\);\n', text)
    assert m and m.group(1) == mid
    return base64.b64decode(m.group(2))


def test_static_model_is_the_obj_in_gltf_axes(tmp_path):
    mesh = trimesh.creation.box()
    v = np.asarray(mesh.vertices) + [0.1, 0.2, 3.0]
    trimesh.Trimesh(v, mesh.faces, process=False).export(tmp_path / "body.obj")
    glb = models.static_glb({"body": tmp_path / "body.obj"})
    back = trimesh.load(trimesh.util.wrap_as_stream(glb), file_type="glb", force="mesh", process=False)
    # camera frame (y down, z forward) -> glTF (y up, z towards the viewer): y and z change sign
    assert np.allclose(np.sort(back.vertices, 0), np.sort(v * [1, -1, -1], 0), atol=1e-6)
    doc, _ = models.read_glb(glb)
    colour = doc["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"]
    assert colour == pytest.approx(models.COLOURS["body"], abs=1 / 255)  # stored in 8 bits


def test_slim_model_keeps_skeleton_and_motion_drops_blend_shapes(body, tmp_path):
    dresser = Dresser("tshirt-trousers")
    torch.manual_seed(0)
    rot = roma.rotvec_to_rotmat(0.2 * torch.randn(4, 24, 3))
    transl = torch.tensor([[0.3 * i, 0.9 + 0.01 * i, -0.2 * i] for i in range(4)])  # walking
    full = write_glb(tmp_path / "a.glb", body, body.mean_shape, rot, transl, 30.0,
                     outfit_animation(body, body.mean_shape, rot, transl, dresser, 30.0))
    slim = tmp_path / "slim.glb"
    slim.write_bytes(models.slim_glb(full.read_bytes()))
    assert slim.stat().st_size < 0.5 * full.stat().st_size
    assert_valid(slim)  # the Khronos validator: a well-formed file (weights sum to 1 again)
    (doc, acc), (doc0, acc0) = read_glb(slim), read_glb(full)
    for mesh, mesh0 in zip(doc["meshes"], doc0["meshes"], strict=True):
        prim, prim0 = mesh["primitives"][0], mesh0["primitives"][0]
        assert "targets" not in prim and set(prim["attributes"]) == {"POSITION", "NORMAL", "JOINTS_0", "WEIGHTS_0"}
        assert np.array_equal(acc(prim["attributes"]["POSITION"]), acc0(prim0["attributes"]["POSITION"]))
        assert np.array_equal(acc(prim["attributes"]["JOINTS_0"]), acc0(prim0["attributes"]["JOINTS_0"]))
        w, w0 = acc(prim["attributes"]["WEIGHTS_0"]), acc0(prim0["attributes"]["WEIGHTS_0"])
        assert np.allclose(w.sum(1), 1, atol=1e-6) and np.allclose(w, w0 / w0.sum(1, keepdims=True), atol=1e-6)
    (moved,) = [c for c in doc["animations"][0]["channels"] if c["target"]["path"] == "translation"]
    path = acc(doc["animations"][0]["samplers"][moved["sampler"]]["output"])
    assert np.allclose(path[:, [0, 2]], 0) and np.allclose(path[:, 1], transl[:, 1].numpy())  # in place, same height
    paths = [c["target"]["path"] for c in doc["animations"][0]["channels"]]
    assert "weights" not in paths and paths.count("rotation") == 24
    rot_ch = [c for c in doc["animations"][0]["channels"] if c["target"]["path"] == "rotation"]
    rot_ch0 = [c for c in doc0["animations"][0]["channels"] if c["target"]["path"] == "rotation"]
    for c, c0 in zip(rot_ch, rot_ch0, strict=True):
        out = acc(doc["animations"][0]["samplers"][c["sampler"]]["output"])
        out0 = acc0(doc0["animations"][0]["samplers"][c0["sampler"]]["output"])
        assert c["target"]["node"] == c0["target"]["node"] and np.array_equal(out, out0)


def test_run_page_lists_results_and_what_was_not_found(tmp_path):
    out = _run_folder(tmp_path / "run")
    index = rpage.write_page(out)
    assert index == out / "index.html" and rpage.folder_kind(out) == "run"
    html = index.read_text()
    assert "https://" not in html and "http://" not in html  # nothing from the network
    d = _data(out)
    assert [i["key"] for i in d["items"]] == ["img0000", "img0001"]
    first = d["items"][0]
    assert [im["src"] for im in first["images"]] == ["img0000/overlay.png"]
    person = first["people"][0]
    assert [v["label"] for v in person["views"]] == ["dressed", "body"]  # dressed first
    assert ["confidence", 0.812] in person["numbers"] and ["focal (px)", "500 (exif)"] in person["numbers"]
    assert ["outfit", "tshirt-trousers"] in person["numbers"]
    why = {m["key"]: m["why"] for m in d["missing"]}
    assert why == {"empty": "no person found", "/data/notes.txt": "skipped: not an image",
                   "/data/bad.jpg": "failed: cannot write outputs (disk full)"}
    assert [m["image"]["src"] for m in d["missing"] if m["image"]] == ["../empty.png"]
    ids = {v["id"] for i in d["items"] for p in i["people"] for v in p["views"]}
    assert {p.stem for p in (out / ".recon-page" / "models").glob("*.js")} == ids
    for mid in ids:  # every model is a valid glb the page can decode
        doc, _ = models.read_glb(_model(out, mid))
        assert doc["asset"]["version"] == "2.0"
    for asset in ("page.js", "page.css", "data.js"):
        assert (out / ".recon-page" / asset).is_file()


def test_page_written_again_remakes_only_what_changed(tmp_path):
    out = _run_folder(tmp_path / "run", n=3)
    rpage.write_page(out)
    before = {p.name: p.stat().st_mtime_ns for p in (out / ".recon-page" / "models").glob("*.js")}
    time.sleep(0.01)
    mesh = trimesh.creation.icosphere(subdivisions=2)
    _result(out / "img0001", np.asarray(mesh.vertices) + [0, 0, 3.0], np.asarray(mesh.faces))  # made again
    import shutil
    shutil.rmtree(out / "img0002")  # gone
    rpage.write_page(out)
    after = {p.name: p.stat().st_mtime_ns for p in (out / ".recon-page" / "models").glob("*.js")}
    assert len(after) == 3  # img0000: dressed + body, img0001: body
    kept = set(before) & set(after)
    assert len(kept) == 2 and all(before[k] == after[k] for k in kept)  # img0000's models untouched
    assert [i["key"] for i in _data(out)["items"]] == ["img0000", "img0001"]


def test_several_people_and_kinds_of_folders(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=1)
    out = tmp_path / "run"
    for i in range(2):
        _result(out / "group" / f"person_{i}", np.asarray(mesh.vertices) + [i, 0, 3], np.asarray(mesh.faces))
    (out / "group" / "people.json").write_text(json.dumps({"source": "g.jpg", "people": [
        {"folder": "person_0"}, {"folder": "person_1"}]}))
    rpage.write_page(out)
    (item,) = _data(out)["items"]
    assert item["key"] == "group" and [p["label"] for p in item["people"]] == ["person 0", "person 1"]
    (tmp_path / "empty").mkdir()
    assert rpage.folder_kind(tmp_path / "empty") is None
    with pytest.raises(FileNotFoundError, match="holds no output"):
        rpage.write_page(tmp_path / "nothing")


def test_a_failing_page_never_fails_the_run(tmp_path, monkeypatch):
    def boom(out, kind=None):
        raise RuntimeError("disk on fire")
    monkeypatch.setattr(build, "write_page", boom)
    lines = []
    assert build.try_write_page(tmp_path, lines.append) is None
    assert lines == ["note: no results page written (RuntimeError: disk on fire)"]


def test_without_the_viewer_the_page_says_so(tmp_path, monkeypatch):
    monkeypatch.setattr(build, "VENDOR", tmp_path / "nowhere")
    out = _run_folder(tmp_path / "run", n=1)
    rpage.write_page(out)
    assert _data(out)["viewer"] is False and "model-viewer" not in (out / "index.html").read_text()


def test_recon_view_writes_the_page_and_prints_its_path(tmp_path, capsys, monkeypatch):
    out = _run_folder(tmp_path / "run", n=1)
    opened = []
    monkeypatch.setattr(build.webbrowser, "get", lambda: type("B", (), {"open": lambda self, u: opened.append(u)})())
    assert main(["view", str(out)]) == 0
    assert capsys.readouterr().out.splitlines()[0] == str((out / "index.html").resolve())
    assert opened == [(out / "index.html").resolve().as_uri()]
    assert main(["view", str(tmp_path / "missing"), "--no-open"]) == 2


# --- in a browser ------------------------------------------------------------------------------

def _viewer_pixels(c: Chromium, n: int = 0) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    box = c.eval(f"(() => {{ const r = document.querySelectorAll('.viewer')[{n}].getBoundingClientRect();"
                 f" return [r.x, r.y, r.width, r.height]; }})()")
    x, y, w, h = (int(round(b)) for b in box)
    return c.screenshot()[y + 2:y + h - 2, x + 2:x + w - 2], (x, y, w, h)


def _painted(pixels: np.ndarray) -> float:
    return float((np.abs(pixels.astype(int) - VIEWER_BG).sum(-1) > 30).mean())


def _errors(c: Chromium) -> list:
    return [m for m in c.console if m[0] in ("error", "exception", "assert")]


@pytest.mark.slow
@needs_chromium
@needs_viewer
def test_browser_shows_a_run_and_plays_an_animation(body, tmp_path):
    out = _run_folder(tmp_path / "run", n=2, mesh=trimesh.Trimesh(
        body.rest_geometry(body.mean_shape[None])[0][0].numpy() * [1, -1, -1] + [0, 0.3, 3], body.faces.numpy()))
    rpage.write_page(out)
    anim = tmp_path / "anim"
    anim.mkdir()
    t = torch.linspace(0, 1, 30)[:, None]
    rotvec = torch.zeros(30, 24, 3)
    rotvec[:, 0, 1] = 3.0 * t[:, 0]  # a turn about the vertical axis: every frame looks different
    rotvec[:, 16, 2], rotvec[:, 17, 2] = -1.2 * t[:, 0], 1.2 * t[:, 0]
    rot, transl = roma.rotvec_to_rotmat(rotvec), torch.tensor([[0.0, 0.9, 0.0]] * 30)
    outfit = outfit_animation(body, body.mean_shape, rot, transl, Dresser("tshirt-trousers", dynamics=False), 15.0)
    write_glb(anim / "animated.glb", body, body.mean_shape, rot, transl, 15.0, outfit)  # 4 influences a vertex
    (anim / "animation.json").write_text(json.dumps({"source": "x", "motion": "turn", "frames": 30, "fps": 15.0,
                                                     "files": {"glb": "animated.glb"}}))
    rpage.write_page(anim)
    with Chromium() as c:
        c.open(out / "index.html")
        assert c.eval("RECON_STATE.cards") == 2
        c.wait_for("RECON_STATE.loaded >= 2", timeout=120)
        assert c.eval("document.querySelectorAll('#missing li').length") == 3
        time.sleep(0.5)
        pixels, _ = _viewer_pixels(c)
        assert _painted(pixels) > 0.02  # the dressed body is drawn
        assert not _errors(c), c.console
        c.open(anim / "index.html")
        c.wait_for("RECON_STATE.loaded >= 1", timeout=120)
        time.sleep(0.5)
        a, _ = _viewer_pixels(c)
        moved, deadline = 0.0, time.monotonic() + 15.0  # a loaded machine draws slowly: wait for a new pose
        while moved <= 0.005 and time.monotonic() < deadline:
            time.sleep(0.5)
            b, _ = _viewer_pixels(c)
            moved = (np.abs(a.astype(int) - b.astype(int)).sum(-1) > 30).mean()
        # drawn (an empty viewer paints nothing); the turning body covers ~2 % front-on, less side-on
        assert _painted(a) > 0.008 and _painted(b) > 0.008
        assert moved > 0.005  # it moved
        c.eval("document.querySelector('.controls button').click()")  # pause
        time.sleep(0.3)
        p1, _ = _viewer_pixels(c)
        time.sleep(0.8)
        p2, _ = _viewer_pixels(c)
        assert (np.abs(p1.astype(int) - p2.astype(int)).sum(-1) > 30).mean() < 0.001  # and stopped
        assert not _errors(c), c.console


@pytest.mark.slow
@needs_chromium
@needs_viewer
def test_a_page_of_a_thousand_results_stays_light(tmp_path):
    out = _run_folder(tmp_path / "run", n=1000)
    t0 = time.perf_counter()
    rpage.write_page(out)
    written = time.perf_counter() - t0
    with Chromium() as c:
        t0 = time.perf_counter()
        c.open(out / "index.html")
        assert c.eval("RECON_STATE.cards") == 1000
        opened = time.perf_counter() - t0
        # only what is on screen is loaded: a few viewers, a few images
        assert c.eval("RECON_STATE.viewers") <= 12
        assert c.eval("[...document.images].filter(i => i.complete && i.naturalWidth).length") <= 60
        c.eval("window.scrollTo(0, document.body.scrollHeight / 2)")
        c.wait_for("document.querySelectorAll('.viewer')[500].dataset.loaded", timeout=60)
        assert c.eval("RECON_STATE.viewers") <= 12  # those scrolled away were dropped
        t0 = time.perf_counter()
        c.eval("document.getElementById('filter').value = 'img0999'; "
               "document.getElementById('filter').dispatchEvent(new Event('input'))")
        assert c.eval("[...document.querySelectorAll('.card')].filter(x => x.style.display !== 'none').length") == 1
        filtered = time.perf_counter() - t0
        assert not _errors(c), c.console
    print(f"1000 results: page written in {written:.1f} s, opened in {opened:.1f} s, filtered in {filtered:.2f} s")
    assert opened < 20 and filtered < 5


def test_a_video_page_plays_an_h264_overlay_and_only_links_an_mpeg4_one(tmp_path):
    frames = [np.full((31, 41, 3), 40 * i, np.uint8) for i in range(6)]
    for codec in ("h264", "mpeg4"):
        out = tmp_path / codec
        out.mkdir()
        write_mp4(out / "overlay.mp4", iter(frames), 30.0, (31, 41), browser=codec == "h264")
        (out / "video.json").write_text(json.dumps({"source": "clip.mp4", "frames": 6, "tracks": [],
                                                    "overlay_codec": codec}))
        rpage.write_page(out)
        data = _data(out)
        assert {"href": "overlay.mp4", "label": "overlay.mp4 (the clip with every track's body)"} in data["links"]
        assert [v["src"] for v in data["videos"]] == (["overlay.mp4"] if codec == "h264" else [])
    cap = cv2.VideoCapture(str(tmp_path / "h264" / "overlay.mp4"))
    fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode()
    n = 0
    while cap.read()[0]:
        n += 1
    assert fourcc in ("avc1", "h264") and n == 6
    assert (cap.get(cv2.CAP_PROP_FRAME_WIDTH), cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) == (42, 32)  # padded to even
