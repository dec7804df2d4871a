"""Offscreen rendering of body meshes: pyrender for demo pictures; the synthetic renderer
(``draw_overlay``, ``draw_meshes``, lit per vertex, much faster) for `recon run`'s outputs.

Needs the ``render`` extra and EGL or OSMesa (scripts/setup.sh installs both). The
platform is taken from $PYOPENGL_PLATFORM, default "egl", falling back to "osmesa".
"""
from __future__ import annotations

import importlib
import importlib.util
import os

import numpy as np
import trimesh

from recon import camera
from recon.errors import ReconError
from recon.render import look
from recon.render.normals import vertex_normals
from recon.render.raster import Rasterizer


def _pyrender():
    if importlib.util.find_spec("pyrender") is None:
        raise ReconError("rendering needs the `render` extra (pyrender): run scripts/setup.sh")
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # before PyOpenGL loads
    os.environ.setdefault("PYGLET_HEADLESS", "1")
    if not hasattr(np, "infty"):
        np.infty = np.inf  # pyrender 0.1.45 still uses the numpy<2 alias
    import pyrender  # noqa: PLC0415 - optional extra, and its GL platform must be chosen first

    return pyrender


def gl_camera_pose(eye: np.ndarray, target: np.ndarray, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Camera-to-world pose (4, 4) of an OpenGL camera (looks down its -Z) at ``eye`` looking at
    ``target``, as pyrender takes it; ``recon.render.raster.look_at`` is the OpenCV world-to-camera (R, t)."""
    z = eye - target
    z = z / np.linalg.norm(z)
    x = np.cross(up, z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, y, z, eye
    return pose


_RENDERERS: dict[tuple[int, int], object] = {}
KEEP_RENDERERS = 4  # offscreen renderers kept by size: making and deleting one costs more than a picture


def _kept(pyrender, width: int, height: int):
    """An offscreen renderer of this size, kept for the next picture (the oldest of more than
    ``KEEP_RENDERERS`` sizes is deleted)."""
    key = (width, height)
    if key not in _RENDERERS:
        if len(_RENDERERS) >= KEEP_RENDERERS:
            _delete(_RENDERERS.pop(next(iter(_RENDERERS))))
        _RENDERERS[key] = _offscreen(pyrender, width, height)
    return _RENDERERS[key]


def _delete(renderer) -> None:
    """pyrender's ``OffscreenRenderer.delete`` without its ``eglTerminate``: terminating the EGL
    display ends every context on it, the rasteriser's too (its next picture fails)."""
    platform = renderer._platform
    display, context = getattr(platform, "_egl_display", None), getattr(platform, "_egl_context", None)
    if display is None or context is None:  # OSMesa, or already deleted
        renderer.delete()
        return
    platform.make_current()
    renderer._renderer.delete()
    importlib.import_module("OpenGL.EGL").eglDestroyContext(display, context)
    platform._egl_context = platform._egl_display = None  # else its own clean-up terminates the display
    renderer._renderer = renderer._platform = None


def _offscreen(pyrender, width: int, height: int):
    try:
        return pyrender.OffscreenRenderer(width, height)
    except Exception as e:  # noqa: BLE001 - report which GL platform failed
        raise ReconError(
            f"offscreen OpenGL ({os.environ.get('PYOPENGL_PLATFORM')}) unavailable: {e}. "
            "Run scripts/setup.sh (installs libegl1/libosmesa6) or set PYOPENGL_PLATFORM=osmesa."
        ) from e


def _front_scene(pyrender, meshes: list[tuple[np.ndarray, np.ndarray, tuple]], center: np.ndarray, distance: float,
                 yaw_deg: float):
    """White background, the meshes, a camera ``distance`` from ``center`` seen from the front
    (body frame) turned by ``yaw_deg``, a light from the camera and one from above."""
    scene = pyrender.Scene(bg_color=[1.0, 1.0, 1.0, 1.0], ambient_light=[0.35, 0.35, 0.35])
    for v, f, rgba in meshes:
        tm = trimesh.Trimesh(v, f, process=False)
        mat = pyrender.MetallicRoughnessMaterial(baseColorFactor=list(rgba), metallicFactor=0.0, roughnessFactor=0.8)
        scene.add(pyrender.Mesh.from_trimesh(tm, material=mat, smooth=True))
    yaw = np.radians(yaw_deg)
    eye = center + distance * np.array([np.sin(yaw), 0.15, np.cos(yaw)])
    cam_pose = gl_camera_pose(eye, center)
    scene.add(pyrender.PerspectiveCamera(yfov=np.radians(40.0)), pose=cam_pose)
    scene.add(pyrender.DirectionalLight(intensity=3.0), pose=cam_pose)
    scene.add(pyrender.DirectionalLight(intensity=1.5), pose=gl_camera_pose(center + np.array([1.0, 2.0, 1.0]), center))
    return scene


def render_meshes(meshes: list[tuple[np.ndarray, np.ndarray, tuple]], size=(512, 512), yaw_deg: float = 0.0,
                  distance: float | None = None, center: np.ndarray | None = None) -> np.ndarray:
    """Render [(vertices, faces, rgba)] seen from the front (body frame), rotated by ``yaw_deg``.

    Returns an (H, W, 3) uint8 image on a white background.
    """
    pyrender = _pyrender()
    allv = np.concatenate([m[0] for m in meshes])
    center = 0.5 * (allv.min(0) + allv.max(0)) if center is None else np.asarray(center, float)
    extent = float(np.max(allv.max(0) - allv.min(0)))
    scene = _front_scene(pyrender, meshes, center, distance or 1.6 * extent + 0.5, yaw_deg)
    color, _ = _kept(pyrender, *size).render(scene)
    return np.ascontiguousarray(color[..., :3])


class SequenceRenderer:
    """Frames of an animation with one offscreen renderer (creating one per frame costs more than
    the frame): ``r(meshes, centre, ground_y) -> (H, W, 3) uint8``, meshes in the body frame seen
    from the front turned by ``yaw_deg``, a grey floor at ``ground_y``; ``r.close()`` at the end."""

    def __init__(self, size=(480, 640), yaw_deg: float = 20.0, distance: float = 3.5):
        self.pyrender = _pyrender()
        self.yaw_deg, self.distance = yaw_deg, distance
        self.renderer = _offscreen(self.pyrender, *size)
        floor = trimesh.creation.box(extents=(40.0, 0.01, 40.0))
        mat = self.pyrender.MetallicRoughnessMaterial(baseColorFactor=[0.82, 0.82, 0.8, 1.0], metallicFactor=0.0,
                                                      roughnessFactor=1.0)
        self.floor = self.pyrender.Mesh.from_trimesh(floor, material=mat, smooth=False)

    def __call__(self, meshes: list[tuple[np.ndarray, np.ndarray, tuple]], centre: np.ndarray,
                 ground_y: float) -> np.ndarray:
        scene = _front_scene(self.pyrender, meshes, np.asarray(centre, float), self.distance, self.yaw_deg)
        pose = np.eye(4)
        pose[:3, 3] = [centre[0], ground_y - 0.005, centre[2]]
        scene.add(self.floor, pose=pose)
        color, _ = self.renderer.render(scene)
        return np.ascontiguousarray(color[..., :3])

    def close(self) -> None:
        _delete(self.renderer)


def render_overlay(rgb: np.ndarray, meshes: list[tuple[np.ndarray, np.ndarray, tuple]], k: np.ndarray,
                   alpha: float = 0.75) -> np.ndarray:
    """Render [(vertices, faces, rgba)] given in the OpenCV camera frame of intrinsics ``k``
    over the (H, W, 3) uint8 photo; returns the blended image."""
    pyrender = _pyrender()
    h, w = rgb.shape[:2]
    scene = pyrender.Scene(bg_color=[0.0, 0.0, 0.0, 0.0], ambient_light=[0.3, 0.3, 0.3])
    for v, f, rgba in meshes:
        tm = trimesh.Trimesh(camera.to_view(v), f, process=False)  # OpenGL's camera axes
        mat = pyrender.MetallicRoughnessMaterial(baseColorFactor=list(rgba), metallicFactor=0.0, roughnessFactor=0.7)
        scene.add(pyrender.Mesh.from_trimesh(tm, material=mat, smooth=True))
    far = float(max(np.abs(m[0][:, 2]).max() for m in meshes)) * 2.0 + 1.0
    scene.add(pyrender.IntrinsicsCamera(k[0, 0], k[1, 1], k[0, 2], k[1, 2], znear=0.05, zfar=far))
    scene.add(pyrender.DirectionalLight(intensity=3.0))
    color, depth = _kept(pyrender, w, h).render(scene)
    a = (depth > 0)[..., None] * alpha  # depth, not colour alpha: OSMesa ignores RGBA
    return (rgb * (1 - a) + color[..., :3] * a + 0.5).astype(np.uint8)


# --- fast pictures for `recon run`'s outputs: the synthetic renderer (moderngl), lit per vertex ----

_RASTER: list = []


def _raster(w: int, h: int):
    """The process' rasteriser (``recon.render.raster``) at this size."""
    if not _RASTER:
        _RASTER.append(Rasterizer(w, h))
    return _RASTER[0].set_size(w, h)


def _lit(meshes, light_dirs, ambient: float):
    """One mesh of all ``meshes`` (camera frame) with per-vertex colours: each mesh's colour under
    ``ambient`` plus Lambert light from ``light_dirs`` (towards the lights), normals facing the camera."""
    verts, faces, cols, off = [], [], [], 0
    for v, f, rgba in meshes:
        v = np.asarray(v, np.float64)
        n = vertex_normals(v, np.asarray(f))
        view = -v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
        n = np.where(((n * view).sum(1) < 0)[:, None], -n, n)
        shade = ambient + sum(w * np.maximum(n @ (d / np.linalg.norm(d)), 0.0) for d, w in light_dirs)
        cols.append(np.clip(np.asarray(rgba[:3], np.float64)[None] * shade[:, None], 0, 1))
        verts.append(v)
        faces.append(np.asarray(f) + off)
        off += len(v)
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(cols)


def draw_overlay(rgb: np.ndarray, meshes: list[tuple[np.ndarray, np.ndarray, tuple]], k: np.ndarray,
                 alpha: float = 0.75) -> np.ndarray:
    """``render_overlay`` with the synthetic renderer: meshes in the OpenCV camera frame of ``k``,
    lit from the camera, anti-aliased (twice the size, averaged), blended over the photo."""
    h, w = rgb.shape[:2]
    v, f, c = _lit(meshes, [((0.0, 0.0, -1.0), 0.6), ((0.3, -0.8, -0.4), 0.25)], 0.3)
    k2 = np.array(k, np.float64)
    k2[:2, :2] *= 2
    k2[:2, 2] = 2 * k2[:2, 2] + 0.5
    col, lab, _ = _raster(2 * w, 2 * h).render(v, f, k2, c, flat=False)
    a = (lab >= 0).astype(np.float32)
    cov = 0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2])[..., None] * alpha
    c2 = col.astype(np.float32)
    person = 0.25 * (c2[0::2, 0::2] + c2[1::2, 0::2] + c2[0::2, 1::2] + c2[1::2, 1::2])
    mean = person / np.maximum(cov / max(alpha, 1e-6), 1e-6)  # the covered sub-samples' colour
    return np.clip(rgb * (1 - cov) + mean * cov + 0.5, 0, 255).astype(np.uint8)


def draw_meshes(meshes: list[tuple[np.ndarray, np.ndarray, tuple]], size=(512, 512), yaw_deg: float = 0.0
                ) -> np.ndarray:
    """``render_meshes`` with the synthetic renderer: [(vertices, faces, rgba)] in the body frame
    (+Y up) seen from the front turned by ``yaw_deg``, on white, (H, W, 3) uint8; ``size`` (W, H)."""
    w, h = size
    allv = np.concatenate([m[0] for m in meshes])
    centre = 0.5 * (allv.min(0) + allv.max(0))
    extent = float(np.max(allv.max(0) - allv.min(0)))
    yaw = np.radians(yaw_deg)
    # body -> OpenCV camera: turn by -yaw about +Y, then the half turn about X (the camera faces +Z)
    r = camera.HALF_TURN_X @ np.array([[np.cos(yaw), 0, -np.sin(yaw)], [0, 1, 0], [np.sin(yaw), 0, np.cos(yaw)]])
    f = 0.5 * h / np.tan(np.radians(20.0))  # pyrender's 40 degree field of view
    dist = 1.6 * extent + 0.5
    cam = [((m[0] - centre) @ r.T + [0.0, 0.0, dist], m[1], m[2]) for m in meshes]
    v, fc, c = _lit(cam, [((0.0, 0.0, -1.0), 0.55), ((0.4, -1.0, -0.5), 0.3)], 0.35)
    k = np.array([[2 * f, 0, w + 0.5], [0, 2 * f, h + 0.5], [0, 0, 1.0]])
    col, lab, _ = _raster(2 * w, 2 * h).render(v, fc, k, c, flat=False)
    return look.downsample2(np.where((lab >= 0)[..., None], col, 255))
