"""Fast offscreen rasteriser (moderngl over EGL): RGB, part labels and metric depth in one pass.

Cameras follow OpenCV: x right, y down, z forward, pixels (u, v) = K @ X / Z, row 0 at the top.
Used for dataset rendering and silhouette IoU; pyrender (recon.viz) stays for demo pictures.

The same images on every x86-64 CPU: Mesa's llvmpipe is pinned to one code path
(``recon.kernels``: SSE4.1, 128-bit vectors, no FMA), and the shaders use only exactly rounded
operations (no ``normalize``/``inversesqrt``, whose approximations differ between CPU vendors):
each face's shading is computed on the CPU in float64 and drawn flat.
"""
from __future__ import annotations

from functools import cache

import moderngl
import numpy as np

from recon import kernels
from recon.errors import ReconError

VERT = """
#version 330
uniform mat4 proj;
in vec3 in_pos;
in vec3 in_color;
in float in_shade;
in int in_label;
out vec3 v_color;
out float v_depth;
flat out float v_shade;
flat out int v_label;
void main() {
    vec3 eye = vec3(in_pos.x, -in_pos.y, -in_pos.z);  // OpenCV camera -> OpenGL eye
    gl_Position = proj * vec4(eye, 1.0);
    v_color = in_color;
    v_depth = in_pos.z;
    v_shade = in_shade;
    v_label = in_label;
}
"""
FRAG = """
#version 330
in vec3 v_color;
in float v_depth;
flat in float v_shade;
flat in int v_label;
layout(location = 0) out vec4 f_color;
layout(location = 1) out int f_label;
layout(location = 2) out float f_depth;
void main() {
    f_color = vec4(v_color * v_shade, 1.0);
    f_label = v_label;
    f_depth = v_depth;
}
"""


def face_shading(verts: np.ndarray, faces: np.ndarray, light_dir, ambient: float) -> np.ndarray:
    """Lambert shading of each face (F,) in float64: its normal turned towards the camera, lit from
    ``light_dir`` (from the surface towards the light, camera frame) on top of ``ambient``. Written
    out per component (the same operations, in the same order, as ``np.cross`` and
    ``np.linalg.norm``: the same bits, three times faster)."""
    v = np.asarray(verts, np.float64)
    a, b, c = (v[i] for i in np.ascontiguousarray(np.asarray(faces).T))
    e1, e2 = b - a, c - a
    x = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
    y = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
    z = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    norm = np.maximum(np.sqrt(x * x + y * y + z * z), 1e-30)
    n = np.stack([x / norm, y / norm, z / norm], 1)
    centre = (a + b + c) / 3
    n[n[:, 0] * centre[:, 0] + n[:, 1] * centre[:, 1] + n[:, 2] * centre[:, 2] > 0] *= -1  # face the camera
    ld = np.asarray(light_dir, np.float64)
    return ambient + (1.0 - ambient) * np.maximum(n @ (ld / np.linalg.norm(ld)), 0.0)


def projection(k: np.ndarray, width: int, height: int, near: float = 0.05, far: float = 100.0) -> np.ndarray:
    """OpenGL projection matrix reproducing the pinhole K (see module docstring)."""
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    return np.array([
        [2 * fx / width, 0, 1 - 2 * cx / width, 0],
        [0, 2 * fy / height, 2 * cy / height - 1, 0],
        [0, 0, -(far + near) / (far - near), -2 * far * near / (far - near)],
        [0, 0, -1, 0],
    ], dtype=np.float32)


@cache
def context() -> moderngl.Context:
    """The process' one OpenGL context: moderngl draws into the current one, so every Rasterizer
    shares it."""
    kernels.pin()  # before Mesa loads (a no-op where the command line or the tests did it)
    try:
        return moderngl.create_standalone_context(backend="egl")
    except Exception as e:  # noqa: BLE001 - moderngl raises plain Exceptions
        raise ReconError(f"no EGL OpenGL context ({e}); run scripts/setup.sh (libegl1, libgl1-mesa-dri)") from e


class Rasterizer:
    """Render triangle meshes given in camera coordinates; reuse one instance per process."""

    def __init__(self, width: int = 256, height: int = 256):
        self.ctx = context()
        with self.ctx:
            self.prog = self.ctx.program(vertex_shader=VERT, fragment_shader=FRAG)
        self._fbos: dict[tuple[int, int], moderngl.Framebuffer] = {}
        self.set_size(width, height)

    def set_size(self, width: int, height: int) -> Rasterizer:
        """Render at this size from now on (framebuffers kept per size, in the process' one context,
        made current for each call: pyrender's may be current in between)."""
        if (width, height) not in self._fbos:
            with self.ctx:
                attachments = [self.ctx.renderbuffer((width, height), 4),
                               self.ctx.renderbuffer((width, height), 1, dtype="i4"),
                               self.ctx.renderbuffer((width, height), 1, dtype="f4")]
                self._fbos[(width, height)] = self.ctx.framebuffer(attachments,
                                                                   self.ctx.depth_renderbuffer((width, height)))
        self.w, self.h = width, height
        self.fbo = self._fbos[(width, height)]
        return self

    def render(self, verts: np.ndarray, faces: np.ndarray, k: np.ndarray, colors: np.ndarray | None = None,
               labels: np.ndarray | None = None, light_dir=(0.3, 0.6, 1.0), ambient: float = 0.45,
               flat: bool = True):
        """Returns rgb (H,W,3) uint8, labels (H,W) int32 (-1 = background), depth (H,W) float32 (0 = bg).
        ``flat``: each face shaded by ``face_shading``; False: the vertex colours as they are,
        interpolated over the faces (lit by the caller)."""
        with self.ctx:  # made current for the call (another library's GL context may be), then restored
            return self._render(verts, faces, k, colors, labels, light_dir, ambient, flat)

    def _render(self, verts, faces, k, colors, labels, light_dir, ambient, flat):
        faces = np.ascontiguousarray(faces, dtype=np.int64)
        n = len(verts)
        c = np.full((n, 3), 0.8, np.float32) if colors is None else colors.astype(np.float32)
        lab = np.zeros(n, np.int32) if labels is None else labels.astype(np.int32)
        shade = (face_shading(verts, faces, light_dir, ambient) if flat else np.ones(len(faces))).astype(np.float32)
        corner = faces.reshape(-1)  # one vertex per face corner: the shade is the face's own
        data = np.empty((len(corner), 7), np.float32)
        data[:, :6] = np.concatenate([verts.astype(np.float32), c], 1)[corner]
        data[:, 6] = np.repeat(shade, 3)
        vbo = self.ctx.buffer(data)
        lbo = self.ctx.buffer(np.ascontiguousarray(lab[corner]))
        vao = self.ctx.vertex_array(self.prog, [(vbo, "3f 3f 1f", "in_pos", "in_color", "in_shade"),
                                                (lbo, "i", "in_label")])
        self.prog["proj"].write(projection(k, self.w, self.h).T.copy().tobytes())
        self.fbo.use()
        self.ctx.enable(self.ctx.DEPTH_TEST)
        self.ctx.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self.fbo.clear(0.0, 0.0, 0.0, 0.0)
        vao.render()
        def read(attachment, components, dtype, np_dtype):  # OpenGL rows run bottom-up
            raw = self.fbo.read(components=components, attachment=attachment, dtype=dtype)
            return np.frombuffer(raw, np_dtype).reshape(self.h, self.w, components)[::-1]

        rgb = read(0, 3, "f1", np.uint8)
        labels_img, depth = read(1, 1, "i4", np.int32)[..., 0], read(2, 1, "f4", np.float32)[..., 0]
        vao.release(), vbo.release(), lbo.release()
        mask = depth > 0
        labels_img = np.where(mask, labels_img, -1)
        return rgb.copy(), labels_img.copy(), depth.copy()


def look_at(eye: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World -> OpenCV camera (R, t) of a camera at ``eye`` looking at ``target``, world +Y up."""
    fwd = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    r = np.stack([right, down, fwd])
    return r, -r @ eye


def silhouette_iou(pred_mask: np.ndarray, gt_mask: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1.0 when both are empty)."""
    if pred_mask.shape != gt_mask.shape:
        raise ValueError(f"mask shapes differ: {pred_mask.shape} vs {gt_mask.shape}")
    union = np.logical_or(pred_mask, gt_mask).sum()
    return 1.0 if union == 0 else float(np.logical_and(pred_mask, gt_mask).sum() / union)
