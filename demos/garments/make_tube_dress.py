"""A garment that is not from the outfit generator (``recon.garment.outfits``), to show DeePSD on a
new shape and a new triangulation: a strapless A-line tube dress from the chest to below the knee,
its surface triangulated irregularly (Delaunay over jittered random points, not a grid and not cut
from the body mesh). Writes demos/garments/tube-dress.obj (body frame, metres, +Y up), which
``recon run --outfit`` and ``recon animate --outfit`` take as it is.

    .venv/bin/python demos/garments/make_tube_dress.py
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from scipy.interpolate import RegularGridInterpolator
from scipy.ndimage import uniform_filter1d
from scipy.spatial import Delaunay

from recon.body import default_body
from recon.garment.templates import ARM, J, RestBody

OUT = Path(__file__).resolve().parent / "tube-dress.obj"
SPACING = 0.018  # m between points, about
EASE, FLARE = 0.012, 0.22  # clearance at the chest; radius gained per metre below the hips


def profile(rb: RestBody, heights: np.ndarray, angles: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Body radius (max over +-0.12 rad and +-1.5 cm of height) per height x angle, arms left out."""
    torso = ~np.isin(rb.owner, ARM["left"] + ARM["right"])
    d = rb.v[torso] - centre
    r, phi, y = np.hypot(d[:, 0], d[:, 2]), np.arctan2(d[:, 0], d[:, 2]), rb.v[torso, 1]
    out = np.zeros((len(heights), len(angles)))
    for i, h in enumerate(heights):
        sel = np.abs(y - h) < 0.015
        da = np.abs((phi[sel][None] - angles[:, None] + np.pi) % (2 * np.pi) - np.pi)
        prof = np.where(da < 0.12, r[sel][None], 0.0).max(1)
        ok = prof > 0  # angles without body samples (under the arms): interpolated around the loop
        out[i] = np.interp(angles, angles[ok], prof[ok], period=2 * np.pi) if ok.any() else 0.0
    return out


def main() -> None:
    rb = RestBody(default_body())
    top, hips = rb.j[J["spine3"]][1] + 0.02, rb.j[J["pelvis"]][1]
    bottom = rb.j[J["left_knee"]][1] - 0.08
    centre = np.array([rb.j[J["pelvis"]][0], 0.0, rb.j[J["spine3"]][2]])
    heights, angles = np.linspace(top, bottom, 80), np.linspace(-np.pi, np.pi, 181)
    radius = uniform_filter1d(profile(rb, heights, angles, centre), 9, axis=1, mode="wrap") + EASE
    radius = np.maximum.accumulate(radius, axis=0)  # never narrower further down: an A-line
    radius += FLARE * np.clip(hips - heights, 0.0, None)[:, None]
    rng = np.random.default_rng(7)
    length, circ = top - bottom, 2 * np.pi * radius.mean()
    rows, cols = int(length / SPACING), int(circ / SPACING)
    u = (np.arange(cols)[None] + rng.uniform(-0.35, 0.35, (rows - 1, cols))) / cols * 2 * np.pi
    v = (np.arange(1, rows)[:, None] + rng.uniform(-0.35, 0.35, (rows - 1, cols))) / rows
    ring = np.arange(cols) / cols * 2 * np.pi
    u = np.concatenate([ring, u.ravel(), ring + np.pi / cols])
    v = np.concatenate([np.zeros(cols), v.ravel(), np.ones(cols)])
    # triangulate on a log-polar annulus, conformal to the tube (a row's step in log radius equals
    # a column's in angle), so Delaunay's triangles are the tube's; the seam needs no special case
    radius_of = np.exp(2 * np.pi * rows / cols * v)
    plane = np.stack([radius_of * np.cos(u), radius_of * np.sin(u)], 1)
    tri = Delaunay(plane).simplices
    ring_of = np.where(v == 0, 0, np.where(v == 1, 1, -1))[tri]
    tri = tri[~((ring_of[:, 0] >= 0) & (ring_of == ring_of[:, :1]).all(1))]  # no slivers along a ring
    tri = tri[np.linalg.norm(plane[tri].mean(1), axis=1) > 0.99]  # nothing across the hole
    y = top - v * length
    phi = (u + np.pi) % (2 * np.pi) - np.pi
    r = RegularGridInterpolator((heights[::-1], angles), radius[::-1], bounds_error=False, fill_value=None)(
        np.stack([y, phi], 1))
    verts = np.stack([centre[0] + r * np.sin(phi), y, centre[2] + r * np.cos(phi)], 1)
    m = trimesh.Trimesh(verts, tri, process=True)
    trimesh.repair.fix_winding(m)
    m.export(OUT)
    print(OUT, len(m.vertices), "vertices", len(m.faces), "faces")


if __name__ == "__main__":
    main()
