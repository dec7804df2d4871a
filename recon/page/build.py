"""``index.html`` for an output folder of ``recon run``, ``recon video``, ``recon animate`` or
``recon demo``: a page that works from the file system, without a server or network.

The page is ``index.html`` plus ``.recon-page/``: the script and style (``recon/page/assets``), the
folder's data (``data.js``: what was found, what was not and why, the numbers of each result),
the 3D viewer (Google's model-viewer, installed by scripts/setup.sh; without it the page shows
everything but the 3D views) and one script per 3D model (``recon.page.models``). Models are
named by their sources' paths, sizes and times, so a page written again (a resumed run) makes
only the models of new or changed results and drops those of results that are gone.
"""
from __future__ import annotations

import html
import json
import logging
import os
import shutil
import webbrowser
from dataclasses import dataclass, field
from pathlib import Path

from recon import paths
from recon.page.models import model_id, slim_glb, static_glb, write_model_script
from recon.version import __version__

log_ = logging.getLogger("recon.page")
ASSETS = Path(__file__).parent / "assets"
VENDOR = Path(__file__).parent / "vendor"  # scripts/setup.sh puts model-viewer here
VIEWER, VIEWER_LICENSE = "model-viewer-umd.min.js", "model-viewer.LICENSE"
PAGE_DIR = ".recon-page"  # beside index.html; hidden: no image's result folder can have this name
BROWSER_IMAGES = {".jpg", ".jpeg", ".png", ".gif", ".webp", ".bmp"}  # what an <img> shows in every browser


def viewer_installed() -> bool:
    return (VENDOR / VIEWER).is_file() and (VENDOR / VIEWER_LICENSE).is_file()


@dataclass
class View:
    """One 3D view: a model made from ``sources`` (``kind``: static from OBJ files, or a slim copy of
    an animated glb), shown under ``label``; ``file``: the full-detail file the page links to."""

    label: str
    kind: str  # "static" | "animated"
    sources: dict[str, Path]
    file: Path


@dataclass
class Page:
    kind: str
    title: str
    root: Path
    summary: list = field(default_factory=list)  # [label, value] rows at the top
    items: list = field(default_factory=list)
    missing: list = field(default_factory=list)  # {"key", "why", "image"?}
    links: list = field(default_factory=list)  # {"href", "label"} for the whole folder
    videos: list = field(default_factory=list)  # {"src", "label"}: clips a browser plays (H.264), shown on top
    views: dict = field(default_factory=dict)  # model id -> View

    def rel(self, path: Path) -> str:
        return Path(os.path.relpath(path, self.root)).as_posix()

    def files(self, folder: Path, names) -> list[dict]:
        """Links to the files ``names`` of ``folder`` that exist."""
        return [{"href": self.rel(folder / n), "label": n} for n in names if (folder / n).is_file()]

    def view(self, v: View) -> dict:
        mid = model_id(list(v.sources.values()), v.kind, self.root)
        self.views[mid] = v
        return {"label": v.label, "id": mid, "animated": v.kind == "animated", "file": self.rel(v.file)}


def _json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _number(x, digits=3):
    return round(x, digits) if isinstance(x, float) else x


def person_numbers(r: dict) -> list:
    """The rows a person's card shows from its result.json."""
    rows = [["found by", r.get("found_by")], ["confidence", r.get("confidence")],
            ["person score", r.get("person_score")], ["height (m)", r.get("height_m")],
            ["reprojection (px)", r.get("reprojection_error_px")], ["shape confidence", r.get("shape_confidence")]]
    rows += [[f"shape: {k}", v] for k, v in (r.get("shape") or {}).items()]
    cam = r.get("camera") or {}
    if cam.get("K"):
        rows.append(["focal (px)", f"{cam['K'][0][0]:g} ({cam.get('focal_from', '?')})"])
    if r.get("outfit"):
        rows.append(["outfit", r["outfit"].get("name")])
    return [[k, _number(v)] for k, v in rows if v is not None]


def _person(page: Page, folder: Path, label: str) -> dict | None:
    r = _json(folder / "result.json")
    if r is None:
        return None
    views = []  # the dressed body first where there is an outfit
    if (folder / "outfit.obj").is_file() and (folder / "body.obj").is_file():
        views.append(page.view(View("dressed", "static", {"body": folder / "body.obj", "outfit": folder / "outfit.obj"},
                                    folder / "dressed.glb")))
    if (folder / "body.obj").is_file():
        views.append(page.view(View("body", "static", {"body": folder / "body.obj"}, folder / "body.glb")))
    return {"label": label, "numbers": person_numbers(r), "views": views,
            "files": page.files(folder, r.get("files", []))}


def _image(page: Page, path: Path, label: str) -> dict | None:
    return {"src": page.rel(path), "label": label} if path.is_file() else None


def _source_image(page: Page, source: str | None) -> dict | None:
    if source and Path(source).suffix.lower() in BROWSER_IMAGES and Path(source).is_file():
        return _image(page, Path(source), "input")
    return None


def run_page(out: Path, page: Page | None = None, prefix: str = "") -> Page:
    """The items of a ``recon run`` folder: every complete result folder under ``out`` (one person,
    or person_<i>/ with people.json), and from summary.json what was not found, skipped or failed."""
    page = page or Page("run", f"recon run: {out.resolve().name}", out)
    found = sorted({p.parent for name in ("result.json", "people.json") for p in out.rglob(name)
                    if not any(part.startswith(".") or part == PAGE_DIR for part in p.relative_to(out).parts)
                    and not (p.name == "result.json" and (p.parent.parent / "people.json").is_file())})
    for folder in found:
        key = prefix + folder.relative_to(out).as_posix()
        people_index = _json(folder / "people.json")
        if people_index is not None:
            people = [_person(page, folder / p["folder"], f"person {i}") for i, p in enumerate(people_index["people"])]
            source = people_index.get("source")
        else:
            people = [_person(page, folder, "person")]
            source = (_json(folder / "result.json") or {}).get("source")
        images = [_image(page, folder / "overlay.png", "overlay"), _image(page, folder / "side.png", "side view")]
        if len(people) > 1 or images[0] is None:
            images.append(_source_image(page, source))
        page.items.append({"key": key, "images": [i for i in images if i], "people": [p for p in people if p]})
    summary = _json(out / "summary.json") or {}
    for key, source in (summary.get("no_person") or {}).items():
        page.missing.append({"key": prefix + key, "why": "no person found", "image": _source_image(page, source)})
    for what in ("skipped", "failed"):
        for path, why in (summary.get(what) or {}).items():
            page.missing.append({"key": path, "why": f"{what}: {why}", "image": None})
    counts = summary.get("counts")
    if counts:
        page.summary += [["results", len(page.items)]] + [[k.replace("_", " "), v] for k, v in counts.items()]
        if summary.get("interrupted"):
            page.summary.append(["interrupted", "yes: run the same command again to resume"])
    return page


def video_page(out: Path) -> Page:
    v = _json(out / "video.json") or {}
    page = Page("video", f"recon video: {Path(v.get('source', out)).name}", out)
    page.summary = [[k, v.get(k)] for k in ("frames", "fps", "people_found_in", "frames_per_second", "camera",
                                             "camera_turned_degrees") if v.get(k) is not None]
    page.summary.append(["tracks", len(v.get("tracks", []))])
    if v.get("skipped"):
        page.summary.append(["frames skipped", len(v["skipped"])])
    if (out / "overlay.mp4").is_file():
        page.links.append({"href": "overlay.mp4", "label": "overlay.mp4 (the clip with every track's body)"})
        if v.get("overlay_codec") == "h264":
            page.videos.append({"src": "overlay.mp4", "label": "the clip with every track's body | the bodies in 3D"})
    for t in v.get("tracks", []):
        folder = out / t["folder"]
        views = [page.view(View("animated", "animated", {"glb": folder / "animated.glb"}, folder / "animated.glb"))] \
            if (folder / "animated.glb").is_file() else []
        numbers = [["first frame", t.get("first")], ["frames", t.get("frames")], ["seen in", t.get("seen")]]
        portrait = _image(page, folder / "person.jpg", f"track {t['id']}")
        page.items.append({"key": t["folder"], "images": [portrait] if portrait else [], "people": [
            {"label": f"track {t['id']}", "numbers": numbers, "views": views,
             "files": page.files(folder, t.get("files", []))}]})
    for frame, why in (v.get("skipped") or {}).items():
        page.missing.append({"key": f"frame {frame}", "why": f"skipped: {why}", "image": None})
    return page


def animate_page(out: Path) -> Page:
    a = _json(out / "animation.json") or {}
    page = Page("animate", f"recon animate: {Path(a.get('source', out)).name} - {a.get('motion', '')}", out)
    page.summary = [[k, a.get(k)] for k in ("motion", "frames", "fps", "outfit", "garment_model") if a.get(k)]
    files = a.get("files", {})
    images = []
    _render_shown(page, out, files.get("video", ""), "render", images, files.get("video", ""))
    _animation_card(page, out, files, images, "person")
    return page


def _render_shown(page: Page, out: Path, name: str, label: str, images: list, link_label: str) -> None:
    """A render of the folder: a GIF shown on the page, another video linked (``link_label``)."""
    if name.endswith(".gif") and (out / name).is_file():
        images.append(_image(page, out / name, label))
    elif name:
        page.links.append({"href": name, "label": link_label})


def _animation_card(page: Page, out: Path, files: dict, images: list, label: str) -> None:
    """The folder's one card: its images, its animated .glb in the 3D viewer and its files."""
    views = []
    if files.get("glb") and (out / files["glb"]).is_file():
        glb = out / files["glb"]
        views.append(page.view(View("animated", "animated", {"glb": glb}, glb)))
    page.items.append({"key": out.resolve().name, "images": images, "people": [
        {"label": label, "numbers": [], "views": views, "files": page.files(out, files.values())}]})


def author_page(out: Path) -> Page:
    """``recon garment author``'s folder: the authored animation's card, its preview and renders."""
    a = _json(out / "authoring.json") or {}
    page = Page("author", f"recon garment author: {a.get('outfit', '')} - {a.get('motion', '')}", out)
    keys = a.get("keys") or {}
    page.summary = [[k, a.get(k)] for k in ("outfit", "motion", "frames", "fps") if a.get(k)] + [
        ["keyframes", ", ".join(keys) if keys else "none (the default material)"]]
    files = a.get("files", {})
    images = []
    for kind, label in (("preview", "ours | interpolation with the same keys"), ("video", "render")):
        name = files.get(kind, "")
        _render_shown(page, out, name, label, images, f"{name}: {label}")
    _animation_card(page, out, files, images, "outfit")
    return page


def demo_page(out: Path) -> Page:
    page = Page("demo", "recon demo", out)
    if (out / "photos").is_dir():
        run_page(out / "photos", page, prefix="photos/")
    for name, label in (("examples.png", "photo | overlay | side view"), ("bodies.png", "sampled bodies"),
                        ("smplr.png", "SMPLR from noisy joints and landmarks")):
        if (out / name).is_file():
            page.links.append({"href": name, "label": f"{name}: {label}"})
    for gif in sorted(out.glob("*.gif")):
        page.links.append({"href": gif.name, "label": f"{gif.name}: the outfit on a held-out mocap clip"})
    return page


def folder_kind(out: Path) -> str | None:
    """Which command wrote ``out``, from the files it leaves; None when none of them."""
    if (out / "video.json").is_file():
        return "video"
    if (out / "animation.json").is_file():
        return "animate"
    if (out / "authoring.json").is_file():
        return "author"
    if (out / "photos" / "summary.json").is_file():
        return "demo"
    if (out / "summary.json").is_file() or any(out.rglob("result.json")):
        return "run"
    return None


BUILDERS = {"run": run_page, "video": video_page, "animate": animate_page, "author": author_page, "demo": demo_page}


def write_page(out: str | Path, kind: str | None = None) -> Path:
    """Write (or bring up to date) ``out/index.html`` and ``out/.recon-page/``; returns the page's path."""
    out = Path(out)
    kind = kind or folder_kind(out)
    if kind is None:
        raise FileNotFoundError(f"{out} holds no output of recon run, video, animate, garment author or demo")
    page = BUILDERS[kind](out)
    pdir = out / PAGE_DIR
    models = pdir / "models"
    models.mkdir(parents=True, exist_ok=True)
    notes = []
    for mid, v in page.views.items():
        target = models / f"{mid}.js"
        if target.is_file():
            continue
        try:
            glb = static_glb(v.sources) if v.kind == "static" else slim_glb(v.sources["glb"].read_bytes())
            write_model_script(target, mid, glb)
        except (OSError, ValueError) as e:
            notes.append(f"no 3D view of {page.rel(v.file)}: {e}")
    for old in models.glob("*.js"):
        if old.stem not in page.views:
            old.unlink(missing_ok=True)
    viewer = viewer_installed()
    for name in (VIEWER, VIEWER_LICENSE) if viewer else ():
        if not (pdir / name).is_file() or (pdir / name).stat().st_size != (VENDOR / name).stat().st_size:
            paths.atomic_write(pdir / name, lambda t, n=name: shutil.copyfile(VENDOR / n, t))
    for asset in ("page.js", "page.css"):
        paths.atomic_write(pdir / asset, lambda t, a=asset: shutil.copyfile(ASSETS / a, t))
    data = {"kind": page.kind, "title": page.title, "recon": __version__, "dir": PAGE_DIR, "summary": page.summary,
            "items": page.items, "missing": page.missing, "links": page.links, "videos": page.videos,
            "notes": notes, "viewer": viewer}
    paths.write_text(pdir / "data.js", "RECON_PAGE = " + json.dumps(data, separators=(",", ":")) + ";\n")
    viewer_tag = f'<script src="{PAGE_DIR}/{VIEWER}"></script>' if viewer else ""
    text = (ASSETS / "index.html").read_text().replace("{{title}}", html.escape(page.title)).replace(
        "{{viewer}}", viewer_tag).replace("{{dir}}", PAGE_DIR)
    return paths.write_text(out / "index.html", text)


def try_write_page(out: str | Path, log=print, kind: str | None = None) -> Path | None:
    """``write_page``, with any failure reported as one line: a page never fails the run it shows."""
    try:
        return write_page(out, kind)
    except Exception as e:  # noqa: BLE001 - the page is a convenience; the run's files are what matter
        log(f"note: no results page written ({type(e).__name__}: {e})")
        return None


def open_in_browser(index: Path) -> bool:
    """Open the page in the user's browser; False where there is none."""
    try:
        browser = webbrowser.get()
    except webbrowser.Error:
        return False
    return bool(browser.open(Path(index).resolve().as_uri()))
