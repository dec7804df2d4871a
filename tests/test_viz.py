"""`recon run`'s pictures (recon.viz): the synthetic renderer's overlay and views, beside pyrender."""
import numpy as np
import trimesh

from recon import viz

SPHERE = trimesh.creation.icosphere(3)


def _meshes(z: float = 0.0):
    return [(SPHERE.vertices * 0.5 + [0.0, 0.0, z], SPHERE.faces, (0.8, 0.5, 0.3, 1.0))]


def test_a_view_is_the_same_after_pyrender_drew_in_between():
    """pyrender's EGL context becomes the current one when it draws; ours is made current again for
    each picture (before, the second view came out blank)."""
    first = viz.draw_meshes(_meshes(), (120, 160))
    viz.render_meshes(_meshes(), size=(120, 160))
    assert np.array_equal(viz.draw_meshes(_meshes(), (120, 160)), first)


def test_a_view_shows_the_mesh_centred_on_white():
    img = viz.draw_meshes(_meshes(), (120, 160))
    assert img.shape == (160, 120, 3)
    assert (img[0, 0] == 255).all() and (img[80, 60] < 250).any()  # background white, the sphere drawn


def test_an_overlay_covers_the_person_and_leaves_the_rest_of_the_photo():
    photo = np.full((100, 80, 3), 40, np.uint8)
    k = np.array([[100.0, 0, 40], [0, 100.0, 50], [0, 0, 1]])
    out = viz.draw_overlay(photo, _meshes(z=3.0), k)
    assert out.shape == photo.shape and (out[0, 0] == 40).all()
    assert not (out[50, 40] == 40).all()  # the sphere in front of the camera's centre


def test_deleting_a_pyrender_renderer_leaves_the_rasteriser_working():
    """pyrender's own delete terminates the EGL display, which ended the rasteriser's context too
    (its next picture failed: "cannot create buffer"); viz deletes its renderers without that."""
    first = viz.draw_meshes(_meshes(), (120, 160))
    for size in [(64 + 8 * i, 48) for i in range(viz.KEEP_RENDERERS + 2)]:  # more sizes than are kept
        viz.render_meshes(_meshes(), size=size)
    seq = viz.SequenceRenderer(size=(48, 64))
    seq(_meshes(), np.zeros(3), -0.5)
    seq.close()
    assert np.array_equal(viz.draw_meshes(_meshes(), (120, 160)), first)
