"""Fast offscreen rasteriser (moderngl over EGL): RGB, part labels and metric depth in one pass.

Cameras follow OpenCV: x right, y down, z forward, pixels (u, v) = K @ X / Z, row 0 at the top.
Used for dataset rendering and silhouette IoU; pyrender (recon.viz) stays for demo pictures.
"""
from __future__ import annotations

import moderngl
import numpy as np

from recon.errors import ReconError

VERT = """
#version 330
uniform mat4 proj;
in vec3 in_pos;
in vec3 in_color;
in int in_label;
out vec3 v_color;
out vec3 v_pos;
flat out int v_label;
void main() {
    vec3 eye = vec3(in_pos.x, -in_pos.y, -in_pos.z);  // OpenCV camera -> OpenGL eye
    gl_Position = proj * vec4(eye, 1.0);
    v_color = in_color;
    v_pos = in_pos;
    v_label = in_label;
}
"""
FRAG = """
#version 330
uniform vec3 light_dir;
uniform float ambient;
in vec3 v_color;
in vec3 v_pos;
flat in int v_label;
layout(location = 0) out vec4 f_color;
layout(location = 1) out int f_label;
layout(location = 2) out float f_depth;
void main() {
    vec3 n = normalize(cross(dFdx(v_pos), dFdy(v_pos)));
    if (dot(n, v_pos) > 0.0) n = -n;  // face the camera
    float shade = ambient + (1.0 - ambient) * max(dot(n, -light_dir), 0.0);
    f_color = vec4(v_color * shade, 1.0);
    f_label = v_label;
    f_depth = v_pos.z;
}
"""


def projection(k: np.ndarray, width: int, height: int, near: float = 0.05, far: float = 100.0) -> np.ndarray:
    """OpenGL projection matrix reproducing the pinhole K (see module docstring)."""
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    return np.array([
        [2 * fx / width, 0, 1 - 2 * cx / width, 0],
        [0, 2 * fy / height, 2 * cy / height - 1, 0],
        [0, 0, -(far + near) / (far - near), -2 * far * near / (far - near)],
        [0, 0, -1, 0],
    ], dtype=np.float32)


class Rasterizer:
    """Render triangle meshes given in camera coordinates; reuse one instance per process."""

    def __init__(self, width: int = 256, height: int = 256):
        try:
            self.ctx = moderngl.create_standalone_context(backend="egl")
        except Exception as e:  # noqa: BLE001 - moderngl raises plain Exceptions
            raise ReconError(f"no EGL OpenGL context ({e}); run scripts/setup.sh (libegl1, libgl1-mesa-dri)") from e
        self.w, self.h = width, height
        self.prog = self.ctx.program(vertex_shader=VERT, fragment_shader=FRAG)
        self.color = self.ctx.renderbuffer((width, height), 4)
        self.label = self.ctx.renderbuffer((width, height), 1, dtype="i4")
        self.depth_out = self.ctx.renderbuffer((width, height), 1, dtype="f4")
        self.zbuf = self.ctx.depth_renderbuffer((width, height))
        self.fbo = self.ctx.framebuffer([self.color, self.label, self.depth_out], self.zbuf)

    def render(self, verts: np.ndarray, faces: np.ndarray, k: np.ndarray, colors: np.ndarray | None = None,
               labels: np.ndarray | None = None, light_dir=(0.3, 0.6, 1.0), ambient: float = 0.45):
        """Returns rgb (H,W,3) uint8, labels (H,W) int32 (-1 = background), depth (H,W) float32 (0 = bg)."""
        n = len(verts)
        c = np.full((n, 3), 0.8, np.float32) if colors is None else colors.astype(np.float32)
        lab = np.zeros(n, np.int32) if labels is None else labels.astype(np.int32)
        vbo = self.ctx.buffer(np.concatenate([verts.astype(np.float32), c], 1).tobytes())
        lbo = self.ctx.buffer(lab.tobytes())
        ibo = self.ctx.buffer(np.ascontiguousarray(faces, dtype=np.int32).tobytes())
        vao = self.ctx.vertex_array(self.prog, [(vbo, "3f 3f", "in_pos", "in_color"), (lbo, "i", "in_label")],
                                    index_buffer=ibo, index_element_size=4)
        self.prog["proj"].write(projection(k, self.w, self.h).T.copy().tobytes())
        ld = np.asarray(light_dir, np.float32)
        self.prog["light_dir"].value = tuple(-ld / np.linalg.norm(ld))
        self.prog["ambient"].value = ambient
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
        vao.release(), vbo.release(), lbo.release(), ibo.release()
        mask = depth > 0
        labels_img = np.where(mask, labels_img, -1)
        return rgb.copy(), labels_img.copy(), depth.copy()


def silhouette_iou(pred_mask: np.ndarray, gt_mask: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1.0 when both are empty)."""
    if pred_mask.shape != gt_mask.shape:
        raise ValueError(f"mask shapes differ: {pred_mask.shape} vs {gt_mask.shape}")
    union = np.logical_or(pred_mask, gt_mask).sum()
    return 1.0 if union == 0 else float(np.logical_and(pred_mask, gt_mask).sum() / union)
