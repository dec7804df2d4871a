"""Offscreen rendering of body meshes with pyrender (demo pictures, overlays).

Needs the ``render`` extra and EGL or OSMesa (scripts/setup.sh installs both). The
platform is taken from $PYOPENGL_PLATFORM, default "egl", falling back to "osmesa".
"""
from __future__ import annotations

import importlib.util
import os

import numpy as np
import trimesh

from recon import camera
from recon.errors import ReconError


def _pyrender():
    if importlib.util.find_spec("pyrender") is None:
        raise ReconError("rendering needs the `render` extra (pyrender): run scripts/setup.sh")
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # before PyOpenGL loads
    os.environ.setdefault("PYGLET_HEADLESS", "1")
    if not hasattr(np, "infty"):
        np.infty = np.inf  # pyrender 0.1.45 still uses the numpy<2 alias
    import pyrender  # noqa: PLC0415 - optional extra, and its GL platform must be chosen first

    return pyrender


def look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Camera-to-world pose for an OpenGL camera (looks down its -Z)."""
    z = eye - target
    z = z / np.linalg.norm(z)
    x = np.cross(up, z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, y, z, eye
    return pose


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
    cam_pose = look_at(eye, center)
    scene.add(pyrender.PerspectiveCamera(yfov=np.radians(40.0)), pose=cam_pose)
    scene.add(pyrender.DirectionalLight(intensity=3.0), pose=cam_pose)
    scene.add(pyrender.DirectionalLight(intensity=1.5), pose=look_at(center + np.array([1.0, 2.0, 1.0]), center))
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
    renderer = _offscreen(pyrender, *size)
    try:
        color, _ = renderer.render(scene)
    finally:
        renderer.delete()
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
        self.renderer.delete()


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
    renderer = _offscreen(pyrender, w, h)
    try:
        color, depth = renderer.render(scene)
    finally:
        renderer.delete()
    a = (depth > 0)[..., None] * alpha  # depth, not colour alpha: OSMesa ignores RGBA
    return (rgb * (1 - a) + color[..., :3] * a + 0.5).astype(np.uint8)
