"""Image loading and `recon run` robustness: bad files are reported and skipped, outputs are
atomic, an interrupted batch resumes."""
import json

import cv2
import numpy as np
import pytest
import trimesh
from gltf_check import assert_valid, pose_meshes, read_glb
from PIL import Image

from recon import camera, io
from recon.body import skeleton
from recon.cli import build_parser
from recon.demo import EXAMPLES
from recon.errors import ReconError
from recon.fit import FitConfig
from recon.garment import store
from recon.keypoints import MediaPipeSource
from recon.keypoints import available as mediapipe_available
from recon.keypoints.adapter import WEIGHTS as ADAPTER_WEIGHTS
from recon.keypoints.views import pad_image, unview, windows
from recon.people.boxes import box_overlap
from recon.people.mediapipe import MP_MIRROR, MPPose
from recon.pipeline import Reconstructor
from recon.poses.bvh import read_bvh
from recon.reconstruction import ReconstructorConfig
from recon.run import RunOptions, run

needs_pipeline = pytest.mark.skipif(not (mediapipe_available() and ADAPTER_WEIGHTS.exists()),
                                    reason="needs mediapipe (scripts/setup.sh) and the adapter weights")
ASTRONAUT = EXAMPLES / "astronaut.jpg"


def _rgb(h=64, w=48):
    return (np.random.default_rng(0).random((h, w, 3)) * 255).astype(np.uint8)


def test_load_modes(tmp_path):
    rgb = _rgb()
    Image.fromarray(rgb).save(tmp_path / "a.png")
    assert np.array_equal(io.load_image(tmp_path / "a.png"), rgb)
    Image.fromarray(rgb[..., 0]).save(tmp_path / "g.png")  # grayscale -> 3 equal channels
    g = io.load_image(tmp_path / "g.png")
    assert g.shape == (64, 48, 3) and np.array_equal(g[..., 1], rgb[..., 0])
    rgba = np.concatenate([rgb, np.zeros((64, 48, 1), np.uint8)], 2)  # fully transparent -> white
    Image.fromarray(rgba, "RGBA").save(tmp_path / "t.png")
    assert (io.load_image(tmp_path / "t.png") == 255).all()
    a16 = (np.arange(64 * 48).reshape(64, 48) * 20).astype(np.uint16)  # 16-bit -> top 8 bits
    Image.fromarray(a16).save(tmp_path / "d.png")
    d = io.load_image(tmp_path / "d.png")
    assert d.dtype == np.uint8 and d[-1, -1, 0] == round(a16[-1, -1] / 65535 * 255)


def test_exif_focal_length(tmp_path):
    """FocalLengthIn35mmFilm -> focal in units of the longer side (diagonal convention)."""
    exif = Image.Exif()
    exif.get_ifd(io.EXIF_IFD)[io.FOCAL_35MM] = 26
    p = tmp_path / "phone.jpg"
    Image.new("RGB", (400, 300)).save(p, exif=exif)
    assert io.exif_focal_factor(p) == pytest.approx(26 * 500 / 43.27 / 400)  # a 26 mm phone lens: 0.75
    Image.new("RGB", (400, 300)).save(tmp_path / "plain.jpg")
    assert io.exif_focal_factor(tmp_path / "plain.jpg") is None
    (tmp_path / "bad.jpg").write_bytes(b"not an image")
    assert io.exif_focal_factor(tmp_path / "bad.jpg") is None


def test_retry_views_map_back_to_the_image():
    """A detection on a zero-padded, mirrored view of the image, mapped back, lands where the
    same person is in the image (left and right swapped back)."""
    rng = np.random.default_rng(0)
    h, w, pad = 60, 80, 20
    xy = rng.uniform(0, [w, h], (33, 2))
    world = rng.normal(0, 0.3, (33, 3))
    mask = rng.random((h, w)) > 0.5
    mirror = list(MP_MIRROR)
    seen_xy = xy[mirror] + pad
    seen_xy[:, 0] = w + 2 * pad - seen_xy[:, 0]  # what MediaPipe reports on the padded mirror view
    seen_mask = np.pad(mask, pad)[:, ::-1]
    r = unview(MPPose(seen_xy, np.arange(33.0)[mirror], world[mirror] * [-1, 1, 1], seen_mask), pad, True, (h, w))
    np.testing.assert_allclose(r.image_xy, xy, atol=1e-9)
    np.testing.assert_allclose(r.world, world, atol=1e-12)
    np.testing.assert_array_equal(r.visibility, np.arange(33.0))
    np.testing.assert_array_equal(r.mask, mask)
    padded, p = pad_image(np.zeros((h, w, 3), np.uint8), 1.5)
    assert p == 20 and padded.shape == (100, 120, 3)


def test_exif_orientation(tmp_path):
    im = Image.fromarray(_rgb(40, 80))
    exif = im.getexif()
    exif[0x0112] = 6  # rotate 90 degrees clockwise on display
    im.save(tmp_path / "r.jpg", exif=exif)
    assert io.load_image(tmp_path / "r.jpg").shape == (80, 40, 3)


@pytest.mark.parametrize("kind, message", [
    ("truncated", "corrupt or truncated"), ("text", "not an image"), ("empty", "empty file"),
    ("tiny", "too small"), ("missing", "not a file")])
def test_bad_files(tmp_path, kind, message):
    p = tmp_path / "x.jpg"
    if kind == "truncated":
        p.write_bytes(ASTRONAUT.read_bytes()[:20000])
    elif kind == "text":
        p.write_text("not an image at all")
    elif kind == "empty":
        p.write_bytes(b"")
    elif kind == "tiny":
        Image.fromarray(_rgb(16, 16)).save(p)
    with pytest.raises(io.ImageError, match=message):
        io.load_image(p)


def test_huge_refused_before_decoding(tmp_path, monkeypatch):
    Image.fromarray(_rgb(200, 300)).save(tmp_path / "big.png")
    monkeypatch.setattr(io, "MAX_PIXELS", 50_000)
    with pytest.raises(io.ImageError, match="larger than"):
        io.load_image(tmp_path / "big.png")


def test_scan_inputs_keys_and_skipped(tmp_path):
    """Every file seen is either an input with a key of its own or listed with a reason; two
    files never share an output folder (the same name in two folders, a.jpg beside a/)."""
    for d in ("in/sub", "other", "in/a", "in/x"):
        (tmp_path / d).mkdir(parents=True)
    for n in ("in/a.jpg", "in/a.png", "in/b.JPG", "in/sub/c.png", "in/notes.txt", "in/.hidden.png", "in/p.jpg",
              "other/p.jpg", "in/a/d.jpg", "in/noext", "in/x.jpg", "in/x/e.jpg"):
        (tmp_path / n).write_bytes(b"x")
    (tmp_path / "in/dangling.jpg").symlink_to(tmp_path / "nowhere")
    (tmp_path / "in/loop1").symlink_to(tmp_path / "in/loop2")
    (tmp_path / "in/loop2").symlink_to(tmp_path / "in/loop1")
    (tmp_path / "in/sub/up").symlink_to(tmp_path / "in")
    (tmp_path / "in/copy.jpg").symlink_to(tmp_path / "in/b.JPG")
    scan = io.scan_inputs([tmp_path / "in", tmp_path / "other", tmp_path / "in/p.jpg", tmp_path / "nope"])
    keys = {f.path.relative_to(tmp_path).as_posix(): f.key for f in scan.files}
    assert keys == {"in/a.jpg": "a_jpg", "in/a.png": "a_png", "in/a/d.jpg": "a/d", "in/b.JPG": "b",
                    "in/sub/c.png": "sub/c", "in/notes.txt": "notes", "in/noext": "noext", "in/p.jpg": "in/p",
                    "other/p.jpg": "other/p", "in/x.jpg": "x_jpg", "in/x/e.jpg": "x/e"}
    assert len({k.casefold() for k in keys.values()}) == len(keys)
    reasons = {k.replace(str(tmp_path) + "/", ""): v for k, v in scan.skipped.items()}
    assert reasons["in/.hidden.png"].startswith("hidden file")
    assert reasons["in/dangling.jpg"] == "broken symbolic link"
    assert reasons["in/loop1"] == reasons["in/loop2"] == "symbolic link loop"
    assert reasons["in/sub/up"].startswith("symbolic link loop")
    assert reasons["in/copy.jpg"].startswith("the same file as")
    assert reasons["nope"] == "no such file or folder"
    with pytest.raises(FileNotFoundError):
        io.scan_inputs([tmp_path / "nope"])
    assert [f.key for f in io.scan_inputs([tmp_path / "in/loop1", tmp_path / "in/b.JPG"]).files] == ["b"]


def test_long_names_are_shortened_within_file_system_limits(tmp_path):
    name = "é" * 120 + ".jpg"  # 240 bytes in UTF-8
    (tmp_path / name).write_bytes(b"x")
    (key,) = [f.key for f in io.scan_inputs([tmp_path]).files]
    assert len(key.encode()) <= io.MAX_NAME_BYTES and key != name


def test_unwritable_output(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(ReconError, match="not writable"):
        run([ASTRONAUT], tmp_path / "file" / "out", progress=False)


@pytest.fixture(scope="module")
def reconstructor():
    return Reconstructor()


def test_the_api_defaults_are_recon_runs():
    """`recon.Reconstructor()` gives what `recon run` gives: the same source and fit defaults."""
    cfg = ReconstructorConfig()
    args = build_parser().parse_args(["run", "--out", "o"])
    assert (cfg.source, cfg.lift, cfg.retry, cfg.guard) == (args.source, args.lift, args.retry, args.guard)
    assert cfg.retry is True and args.focal is None and cfg.focal_factor == 1.0  # no --focal: EXIF, else the API's
    assert (cfg.fit.steps, cfg.fit.silhouette) == (args.refine_steps, args.silhouette) == (FitConfig().steps,
                                                                                          FitConfig().silhouette)
    assert args.refine_steps == 30
    assert (args.batch_size, args.max_people) == (RunOptions().batch_size, RunOptions().max_people)


@needs_pipeline
def test_pipeline_on_photo(reconstructor):
    rec = reconstructor(io.load_image(ASTRONAUT))
    js = rec.to_json()
    assert len(js["joints3d"]) == 24 and len(js["landmarks2d"]) == 18
    assert rec.joints[0, 2] > 0.5  # in front of the camera
    assert js["reprojection_error_px"] < 0.06 * max(rec.image_size)
    assert reconstructor.fit.steps == 30 and rec.fit["steps"] == 30  # recon run's default fit
    raw = reconstructor.fit
    try:  # the 2D fit brings the model closer to the detected keypoints than SMPLR alone
        reconstructor.fit = FitConfig(steps=0)
        assert reconstructor(io.load_image(ASTRONAUT)).reprojection_error_px > rec.reprojection_error_px
    finally:
        reconstructor.fit = raw
    height = rec.vertices[:, 1].max() - rec.vertices[:, 1].min()
    assert 1.2 < height < 2.2  # a plausible adult (metres)
    # parameters re-posed through the body model give the same mesh (frames are consistent)
    v = reconstructor.posed_body(rec).vertices[0].numpy()
    assert np.abs(v - rec.vertices).max() < 1e-3


@pytest.mark.slow
@needs_pipeline
def test_run_robust_batch_and_resume(tmp_path, reconstructor):
    src = tmp_path / "in"
    src.mkdir()
    (src / "a_photo.jpg").write_bytes(ASTRONAUT.read_bytes())
    gray = np.asarray(Image.open(EXAMPLES / "cameraman.png"))
    Image.fromarray(gray.astype(np.uint16) * 257).save(src / "b_gray16.png")
    (src / "c_corrupt.jpg").write_bytes(ASTRONAUT.read_bytes()[:5000])
    (src / "d_text.png").write_text("hello")
    Image.fromarray(np.full((200, 200, 3), 127, np.uint8)).save(src / "e_nobody.png")
    big = np.asarray(Image.open(ASTRONAUT).resize((4096, 4096)))
    Image.fromarray(big).save(src / "f_huge.jpg", quality=80)
    out = tmp_path / "out"

    class Interrupting:  # Ctrl-C during the second batch
        def __init__(self):
            self.calls, self.faces, self.focal_factor, self.body = 0, reconstructor.faces, 1.0, reconstructor.body
            self.config, self.source = reconstructor.config, reconstructor.source

        def people(self, images, ks, max_people):
            self.calls += 1
            if self.calls == 2:
                raise KeyboardInterrupt
            return reconstructor.people(images, ks, max_people)

    s = run([src], out, RunOptions(batch_size=2, overlay=False), reconstructor=Interrupting(), progress=False,
            log=lambda m: None)
    assert s.interrupted and s.done == ["a_photo", "b_gray16"]
    assert not [p for p in out.rglob(".*") if p.name != ".recon-page"]  # no temporary files left behind
    s = run([src], out, RunOptions(batch_size=2, overlay=False), reconstructor=reconstructor, progress=False,
            log=lambda m: None)
    assert not s.interrupted
    assert sorted(s.unchanged) == ["a_photo", "b_gray16"]
    skipped = {k.rsplit("/", 1)[-1]: v for k, v in s.skipped.items()}
    assert set(skipped) == {"c_corrupt.jpg", "d_text.png"} and s.no_person == {"e_nobody": str(src / "e_nobody.png")}
    assert "truncated" in skipped["c_corrupt.jpg"] and "not an image" in skipped["d_text.png"]
    assert s.done == ["f_huge"] and not s.failed
    huge = json.loads((out / "f_huge" / "result.json").read_text())
    assert huge["image_size"] == [4096, 4096]
    assert huge["fit"] == {"steps": 30, "silhouette": 10.0}  # MediaPipe gives a mask: the fit used it
    assert huge["made_from"]["input_sha256"] == io.file_digest(src / "f_huge.jpg")
    assert huge["camera"]["K"][0][2] == pytest.approx(2048)  # original pixels, not the downscaled ones
    assert max(max(p) for p in huge["joints2d"]) > 1920
    assert {"result.json", "body.obj", "body.glb", "pose.bvh"} <= {p.name for p in (out / "f_huge").iterdir()}
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"] == {"done": 1, "unchanged": 2, "no_person": 1, "skipped": 2, "failed": 0}
    assert not (out / "c_corrupt").exists()  # nothing written for failures


def test_run_tightness_needs_an_outfit_with_a_resizer(tmp_path, monkeypatch):
    quiet = dict(progress=False, log=lambda m: None)
    with pytest.raises(ReconError, match="needs --outfit"):
        run([EXAMPLES], tmp_path / "a", RunOptions(tightness=(0.1, 0.0)), **quiet)
    monkeypatch.setattr(store, "resizer_path", lambda outfit, pbns=None: tmp_path / "none.pt")  # no resizer there
    with pytest.raises(ReconError, match="trained resizer for top-shorts"):
        run([EXAMPLES], tmp_path / "b", RunOptions(outfit="top-shorts", tightness=(0.1, 0.0)), **quiet)
    assert not (tmp_path / "b" / "summary.json").exists()  # refused before any image


@needs_pipeline
def test_mediapipe_flip_is_mirror_equivariant():
    """avg(f(x), M f(Mx)) gives the mirrored answer on the mirrored photo (left/right swapped)."""
    src = MediaPipeSource(flip=True)
    img = io.load_image(ASTRONAUT)
    k = camera.default_intrinsics(*img.shape[:2])
    a, b = src(img, k), src(np.ascontiguousarray(img[:, ::-1]), k)
    mirror = list(skeleton.POINT_MIRROR)
    np.testing.assert_allclose(b.points3d[mirror] * [-1, 1, 1], a.points3d, atol=1e-4)
    np.testing.assert_allclose(img.shape[1] - b.points2d[mirror][:, 0], a.points2d[:, 0], atol=1e-2)
    plain = MediaPipeSource(flip=False)(img, k)
    assert np.abs(plain.points3d - a.points3d).max() > 1e-3  # the averaging did something


@needs_pipeline
def test_run_reads_the_focal_length_from_exif(tmp_path, reconstructor):
    """A photo with a 35 mm equivalent focal length in its EXIF gets that focal (result.json says
    so); the same photo without one gets the reconstructor's default."""
    exif = Image.Exif()
    exif.get_ifd(io.EXIF_IFD)[io.FOCAL_35MM] = 50
    Image.open(ASTRONAUT).save(tmp_path / "exif.jpg", exif=exif)
    Image.open(ASTRONAUT).save(tmp_path / "plain.jpg")
    run([tmp_path / "exif.jpg", tmp_path / "plain.jpg"], tmp_path / "out", RunOptions(overlay=False),
        reconstructor=reconstructor, progress=False, log=lambda m: None)
    with_exif = json.loads((tmp_path / "out" / "exif" / "result.json").read_text())["camera"]
    plain = json.loads((tmp_path / "out" / "plain" / "result.json").read_text())["camera"]
    side = max(io.load_image(ASTRONAUT).shape[:2])
    assert with_exif["focal_from"] == "exif" and plain["focal_from"] == "default"
    assert with_exif["K"][0][0] == pytest.approx(io.exif_focal_factor(tmp_path / "exif.jpg") * side, rel=1e-3)
    assert plain["K"][0][0] == pytest.approx(reconstructor.focal_factor * side, rel=1e-3)
    # pose.bvh: the body's skeleton in the photo's pose; its joints are result.json's (view frame, cm)
    res = json.loads((tmp_path / "out" / "plain" / "result.json").read_text())
    motion = read_bvh(tmp_path / "out" / "plain" / "pose.bvh")
    joints = motion.positions[0, [motion.names.index(n) for n in skeleton.JOINT_NAMES]] / 100.0
    np.testing.assert_allclose(joints, camera.to_view(np.array(res["joints3d"])), atol=2e-4)
    assert "pose.bvh" in res["files"]


@needs_pipeline
def test_run_writes_rigged_glb_files(tmp_path, reconstructor):
    """body.glb / dressed.glb: valid glTF whose skeleton, skin and blend shapes pose the meshes
    where body.obj / outfit.obj are (view frame), with the photo's camera: exactly with every
    skinning influence, and with the default 4 the body within the influences' error and the
    cloth (its post-step target made for the file's weights) exactly."""
    for every in (True, False):
        out = tmp_path / f"out-{every}"
        s = run([ASTRONAUT], out, RunOptions(outfit="tshirt-skirt", overlay=False, all_influences=every),
                reconstructor=reconstructor, progress=False, log=lambda m: None)
        folder = out / s.done[0]
        for name in ("body.glb", "dressed.glb"):
            assert_valid(folder / name)
            sets = {k for m in read_glb(folder / name)[0]["meshes"] for k in m["primitives"][0]["attributes"]
                    if k.startswith("JOINTS")}
            assert (len(sets) > 1) == every
        obj = camera.to_view(np.asarray(trimesh.load(folder / "body.obj", process=False).vertices))
        off = np.linalg.norm(pose_meshes(folder / "body.glb")["body"] - obj, axis=1)
        assert off.max() < 1e-4 if every else (off.mean() < 1e-3 and off.max() < 0.03)
        dressed = pose_meshes(folder / "dressed.glb")
        cloth = camera.to_view(np.asarray(trimesh.load(folder / "outfit.obj", process=False).vertices))
        # the Dresser's post-step is one more morph target: the file's cloth is outfit.obj's
        assert np.median(np.linalg.norm(dressed["outfit"] - cloth, axis=1)) < 1e-4
        assert np.linalg.norm(dressed["outfit"] - cloth, axis=1).mean() < 3e-4
    doc, _ = read_glb(folder / "body.glb")
    js = json.loads((folder / "result.json").read_text())
    h, f = js["image_size"][0], js["camera"]["K"][1][1]
    assert doc["cameras"][0]["perspective"]["yfov"] == pytest.approx(2 * np.arctan(h / 2 / f), rel=1e-3)
    assert [n["name"] for n in doc["nodes"][:24]] == list(skeleton.JOINT_NAMES)


@needs_pipeline
def test_run_finds_every_person(tmp_path, reconstructor):
    """Two photos side by side: --max-people gives person_0/, person_1/, one overlay and
    people.json (the largest person first); one person per image keeps the flat layout."""

    photos = [io.load_image(p) for p in sorted(EXAMPLES.glob("*.jpg"))[:2]]
    h = min(p.shape[0] for p in photos)
    strip = np.concatenate([cv2.resize(p, (round(p.shape[1] * h / p.shape[0]), h)) for p in photos], 1)
    Image.fromarray(strip).save(tmp_path / "two.png")
    quiet = dict(progress=False, log=lambda m: None)
    s = run([tmp_path / "two.png"], tmp_path / "many", RunOptions(max_people=3), reconstructor=reconstructor, **quiet)
    folder = tmp_path / "many" / s.done[0]
    index = json.loads((folder / "people.json").read_text())
    assert index["count"] == 2 and not (folder / "result.json").exists()
    assert (folder / "overlay.png").exists()
    areas = []
    for person in index["people"]:
        js = json.loads((folder / person["folder"] / "result.json").read_text())
        x0, y0, x1, y1 = js["box"]
        areas.append((x1 - x0) * (y1 - y0))
    assert areas[0] >= areas[1]
    centres = [np.mean(json.loads((folder / p["folder"] / "result.json").read_text())["joints2d"], 0)[0]
               for p in index["people"]]
    assert min(centres) < strip.shape[1] / 2 < max(centres)  # one on each side
    again = run([tmp_path / "two.png"], tmp_path / "many", RunOptions(max_people=3), reconstructor=reconstructor,
                **quiet)
    assert again.unchanged == s.done
    one = run([tmp_path / "two.png"], tmp_path / "one", reconstructor=reconstructor, **quiet)
    assert (tmp_path / "one" / one.done[0] / "result.json").exists()


def test_people_windows_cover_the_image():

    for h, w in ((256, 768), (768, 256), (480, 640)):
        wins = windows(h, w)
        cover = np.zeros((h, w), bool)
        for x0, y0, x1, y1 in wins:
            assert 0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h
            cover[y0:y1, x0:x1] = True
        assert cover.all()
    assert box_overlap((0, 0, 10, 10), (2, 2, 5, 5)) == 1.0 and box_overlap((0, 0, 1, 1), (5, 5, 6, 6)) == 0.0
