"""The newton reference drape (optional: runs only where newton is installed)."""
import numpy as np
import pytest
import trimesh

from recon.garment import reference

pytestmark = [pytest.mark.skipif(not reference.available(), reason="newton not installed (pip install recon[sim])"),
              pytest.mark.slow]  # compiles newton's kernels (~35 s) on a fresh machine


def test_drape_rests_on_collider_and_keeps_rest_lengths():
    sphere = trimesh.creation.icosphere(3, 0.15)
    n = 15
    xs = np.linspace(-0.12, 0.12, n)
    rest = np.array([[x, 0.17, z] for z in xs for x in xs])  # 2 cm above the top of the sphere
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            faces += [[a, a + n, a + 1], [a + 1, a + n, a + n + 1]]
    faces = np.array(faces)
    r = reference.drape(sphere.vertices, sphere.faces, rest, rest.copy(), faces, np.zeros(len(rest), bool),
                        reference.DrapeConfig(frames=40))
    v = r["vertices"]
    centre = v[n * n // 2]
    assert 0.15 < centre[1] < 0.15 + 0.01  # came down onto the sphere and stayed on it
    assert (np.linalg.norm(v, axis=1) > 0.15 - 1e-3).all()  # nothing went through
    e = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1), axis=0)
    strain = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1) / np.linalg.norm(rest[e[:, 0]] - rest[e[:, 1]], axis=1)
    assert np.median(np.abs(strain - 1)) < 0.02
    assert r["frames"] <= 40 and len(r["move_history_mm"]) == r["frames"]
