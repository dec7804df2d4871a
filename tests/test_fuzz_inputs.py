"""`recon run` on a generated corpus of odd inputs (made here, nothing downloaded): every file is
accounted for in summary.json with a reason, nothing raises, no folder is left half written; an
interrupted run (kill -9) resumes into complete outputs."""
import io as pyio
import json
import os
import signal
import subprocess
import sys
import time
import zlib

import numpy as np
import pytest
from PIL import Image

from recon import io
from recon.demo import EXAMPLES
from recon.errors import ReconError
from recon.keypoints import available as mediapipe_available
from recon.reconstruction import NoPersonFound, ReconstructorConfig
from recon.run import STAGING, run

ASTRONAUT = EXAMPLES / "astronaut.jpg"


def _png(img: Image.Image, **kw) -> bytes:
    b = pyio.BytesIO()
    img.save(b, format="PNG", **kw)
    return b.getvalue()


def _encoded(img: Image.Image, fmt: str, **kw) -> bytes:
    b = pyio.BytesIO()
    img.save(b, format=fmt, **kw)
    return b.getvalue()


def make_corpus(root):
    """>= 45 odd inputs in ``root/in`` and ``root/other``; returns the inputs to give `recon run`
    and what each file should become: "image" (decodes), "bad" (skipped with a reason)."""
    src, other = root / "in", root / "other"
    src.mkdir()
    other.mkdir()
    photo = Image.open(ASTRONAUT).convert("RGB")
    jpeg = ASTRONAUT.read_bytes()
    png = _png(photo)
    rng = np.random.default_rng(0)
    expect = {}

    def put(name, data, kind, folder=src):
        (folder / name).write_bytes(data)
        expect[str(folder / name)] = kind

    put("empty.jpg", b"", "bad")
    put("random.jpg", rng.integers(0, 256, 5000, dtype=np.uint8).tobytes(), "bad")
    put("random.png", rng.integers(0, 256, 300, dtype=np.uint8).tobytes(), "bad")
    for frac in (0.02, 0.3, 0.6, 0.9):
        put(f"cut{int(frac * 100)}.jpg", jpeg[:int(len(jpeg) * frac)], "bad")
        put(f"cut{int(frac * 100)}.png", png[:int(len(png) * frac)], "bad")
    put("no_end_marker.jpg", jpeg[:-2], "image")
    put("trailing_garbage.jpg", jpeg + b"garbage" * 10, "image")
    for i, pos in enumerate((0.3, 0.5, 0.8)):  # bit flips in the entropy-coded data: decodes, damaged
        data = bytearray(jpeg)
        data[int(len(data) * pos)] ^= 0x10
        put(f"bitflip{i}.jpg", bytes(data), "any")
    header = bytearray(_png(Image.new("L", (8, 8))))
    header[16:24] = (60000).to_bytes(4, "big") * 2  # IHDR claims 60000 x 60000 (with a valid checksum)
    header[29:33] = zlib.crc32(bytes(header[12:29])).to_bytes(4, "big")
    put("bomb.png", bytes(header), "bad")
    put("one_pixel.png", _png(Image.new("RGB", (1, 1))), "bad")
    put("strip.png", _png(Image.new("RGB", (20000, 4))), "bad")
    put("gray.png", _png(photo.convert("L")), "image")
    put("rgba.png", _png(photo.convert("RGBA")), "image")
    put("la.png", _png(photo.convert("LA")), "image")
    put("cmyk.jpg", _encoded(photo.convert("CMYK"), "JPEG"), "image")
    put("palette.png", _png(photo.convert("P")), "image")
    put("one_bit.png", _png(photo.convert("1")), "image")
    put("sixteen_bit.png", _png(Image.fromarray(np.asarray(photo.convert("L"), np.uint16) * 257)), "image")
    put("float.tif", _encoded(Image.fromarray(np.asarray(photo.convert("L"), np.float32) / 255), "TIFF"), "image")
    put("photo.tif", _encoded(photo, "TIFF"), "image")
    put("photo.webp", _encoded(photo, "WEBP"), "image")
    put("photo.bmp", _encoded(photo, "BMP"), "image")
    put("photo.ppm", _encoded(photo, "PPM"), "image")
    put("photo.ico", _encoded(photo.resize((64, 64)), "ICO"), "image")
    frames = [photo.resize((128, 128)), photo.resize((128, 128)).rotate(90)]
    put("animated.gif", _encoded(frames[0], "GIF", save_all=True, append_images=frames[1:]), "image")
    exif = photo.getexif()
    exif[0x0112] = 6
    put("rotated.jpg", _encoded(photo, "JPEG", exif=exif), "image")
    put("no_extension", jpeg, "image")
    put("wrong_extension.png", jpeg, "image")
    put("notes.txt", b"not an image\n", "bad")
    put("drawing.svg", b'<svg xmlns="http://www.w3.org/2000/svg"><circle r="4"/></svg>', "bad")
    put("document.jpg", b"%PDF-1.4\n%\xe2\xe3\xcf\xd3\n1 0 obj\n<<>>\nendobj\n", "bad")
    put("archive.png", b"PK\x03\x04" + bytes(100), "bad")
    put("fake.heic", b"\x00\x00\x00\x18ftypheic" + bytes(40), "bad")
    put("ünïcødé 写真.jpg", jpeg, "image")
    put("x" * 251 + ".jpg", jpeg, "image")
    put(".hidden.jpg", jpeg, "hidden")
    put("p.jpg", jpeg, "image")
    put("p.jpg", _png(photo.transpose(Image.Transpose.FLIP_LEFT_RIGHT)), "image", folder=other)
    (src / "folder.jpg").mkdir()  # a folder named like an image: walked
    put("inside.png", png, "image", folder=src / "folder.jpg")
    (src / "loop_a").symlink_to(src / "loop_b")
    (src / "loop_b").symlink_to(src / "loop_a")
    expect[str(src / "loop_a")] = expect[str(src / "loop_b")] = "bad"
    (src / "dangling.jpg").symlink_to(root / "nowhere.jpg")
    expect[str(src / "dangling.jpg")] = "bad"
    (src / "up").symlink_to(src)  # a folder loop
    (root / "loop_c").symlink_to(root / "loop_d")
    (root / "loop_d").symlink_to(root / "loop_c")
    expect[str(root / "loop_c")] = "bad"
    assert len(expect) >= 45
    return [src, other, root / "loop_c"], expect


class StubReconstructor:
    """Finds nobody anywhere: the corpus test exercises reading and accounting, not the networks."""

    config = ReconstructorConfig()
    focal_factor = 1.0

    def people(self, images, ks, max_people):
        return [NoPersonFound("no person found") for _ in images]


def _accounted(summary: dict, expect: dict, out) -> None:
    """Every file of the corpus is in summary.json once, as the corpus says it should be."""
    listed = {}
    for key in summary["done"] + summary["unchanged"]:
        listed[json.loads((out / key / "result.json").read_text())["source"]] = "image"
    for src in summary["no_person"].values():
        listed[src] = "image"
    for path in summary["skipped"]:
        listed[path] = "bad"
    for path in summary["failed"]:
        listed[path] = "failed"
    for path, kind in expect.items():
        assert path in listed or kind == "hidden" and path in summary["skipped"], f"{path} not in summary.json"
        if kind in ("image", "bad"):
            assert listed[path] == kind, (path, listed[path], summary["skipped"].get(path))
    assert not summary["failed"], summary["failed"]


def test_every_odd_input_is_accounted_for(tmp_path):
    inputs, expect = make_corpus(tmp_path)
    out = tmp_path / "out"
    s = run(inputs, out, reconstructor=StubReconstructor(), progress=False, log=lambda m: None)
    summary = json.loads((out / "summary.json").read_text())
    _accounted(summary, expect, out)
    reasons = summary["skipped"]
    assert "decompression bomb" in reasons[str(tmp_path / "in" / "bomb.png")]
    assert "too small" in reasons[str(tmp_path / "in" / "one_pixel.png")]
    assert "truncated" in reasons[str(tmp_path / "in" / "cut60.jpg")]
    assert reasons[str(tmp_path / "loop_c")] == "symbolic link loop"
    assert reasons[str(tmp_path / "in" / "dangling.jpg")] == "broken symbolic link"
    assert "HEIC" in reasons[str(tmp_path / "in" / "fake.heic")] or "not an image" in reasons[
        str(tmp_path / "in" / "fake.heic")]
    two = {k for k, v in summary["no_person"].items() if v.endswith("/p.jpg")}
    assert len(two) == 2  # the same name in two folders: two outputs
    assert set(s.no_person) == set(summary["no_person"])
    assert not [p for p in out.rglob(".*") if p.name != ".recon-page"] and not (out / STAGING).exists()


def test_a_read_only_output_folder_is_refused_before_any_image(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    out.chmod(0o500)
    try:
        if os.access(out, os.W_OK):
            pytest.skip("running as a user who can write anywhere (root)")
        with pytest.raises(ReconError, match="not writable"):
            run([ASTRONAUT], out, reconstructor=StubReconstructor(), progress=False, log=lambda m: None)
    finally:
        out.chmod(0o700)


def test_a_jpeg_without_its_end_marker_decodes_and_a_cut_one_is_refused(tmp_path):
    jpeg = ASTRONAUT.read_bytes()
    (tmp_path / "eoi.jpg").write_bytes(jpeg[:-2])
    (tmp_path / "cut.jpg").write_bytes(jpeg[:len(jpeg) // 2])
    np.testing.assert_array_equal(io.load_image(tmp_path / "eoi.jpg"), io.load_image(ASTRONAUT))
    with pytest.raises(io.ImageError, match="truncated"):
        io.load_image(tmp_path / "cut.jpg")


@pytest.mark.skipif(io.register_heif_opener is None, reason="pillow-heif not installed")
def test_heic_phone_photos_load(tmp_path):
    Image.open(ASTRONAUT).save(tmp_path / "phone.heic")
    assert io.load_image(tmp_path / "phone.heic").shape == (512, 512, 3)


@pytest.mark.slow
@pytest.mark.skipif(not mediapipe_available(), reason="needs mediapipe (scripts/setup.sh)")
def test_kill_9_then_rerun_gives_complete_outputs(tmp_path):
    """`recon run` killed with SIGKILL mid-batch, then run again: every image folder complete
    (result.json and every file it lists), none twice, no staging or temporary files."""
    src = tmp_path / "in"
    src.mkdir()
    photo = Image.open(ASTRONAUT)
    for i in range(6):  # different bytes each: a fresh reconstruction each
        photo.rotate(i * 3, fillcolor=(255, 255, 255)).save(src / f"photo{i}.jpg")
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "recon.cli", "run", str(src), "--out", str(out), "--no-overlay", "--batch-size", "1",
           "--refine-steps", "5"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.time() + 300
    while time.time() < deadline and not list(out.glob("*/result.json")):
        time.sleep(0.2)
    time.sleep(1.0)  # into the next image's writing
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    first = {p.parent.name for p in out.glob("*/result.json")}
    assert 1 <= len(first) < 6
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert "W0000" not in done.stderr and "INFO" not in done.stderr  # third-party log noise hidden
    summary = json.loads((out / "summary.json").read_text())
    assert sorted(summary["done"] + summary["unchanged"]) == [f"photo{i}" for i in range(6)]
    assert set(summary["unchanged"]) == first
    for folder in out.iterdir():
        if folder.is_dir() and folder.name != ".recon-page":
            js = json.loads((folder / "result.json").read_text())
            assert set(js["files"]) <= {p.name for p in folder.iterdir()}
    assert not [p for p in out.rglob(".*") if p.name != ".recon-page"]  # the page's folder, no temp files
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [f"photo{i}" for i in range(6)] + ["summary.json", "index.html", ".recon-page"])
