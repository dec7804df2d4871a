"""The other domain's look: materials, lighting and the camera (``recon.synth.other``).

Unlike the training generator's flat-shaded faces under one light, the other domain shades every
vertex (smooth normals) under a key, a fill and a rim light of their own colours plus a sky/ground
ambient, with Blinn-Phong highlights per material, in linear light with a gamma; the frame is
rendered at twice the size and averaged (anti-aliasing), then goes through a camera: defocus,
white balance, vignetting, sensor noise and JPEG compression. Garments carry printed patterns
(stripes, plaid, checks, dots, denim, photo prints) on their rest-pose coordinates.

Only exactly rounded float operations reach a pixel (no SIMD-dependent transcendental functions
in float32): the shading of a given mesh is the same bits on every x86-64 CPU.
"""
from __future__ import annotations

import cv2
import numpy as np

from recon.body import skeleton

J = {n: i for i, n in enumerate(skeleton.JOINT_NAMES)}
# clothing colours people wear (sRGB): blacks, greys, whites, navy, denim, earth tones, a few bright
PALETTE = np.array([
    [0.08, 0.08, 0.09], [0.20, 0.20, 0.22], [0.45, 0.45, 0.47], [0.75, 0.75, 0.74], [0.93, 0.93, 0.91],
    [0.12, 0.16, 0.32], [0.25, 0.35, 0.55], [0.55, 0.65, 0.80], [0.40, 0.30, 0.20], [0.70, 0.60, 0.45],
    [0.85, 0.78, 0.62], [0.30, 0.35, 0.20], [0.55, 0.10, 0.12], [0.80, 0.20, 0.15], [0.95, 0.75, 0.20],
    [0.20, 0.50, 0.35], [0.60, 0.35, 0.55], [0.90, 0.55, 0.60], [0.15, 0.45, 0.60], [0.50, 0.25, 0.10]])
HAIR = np.array([[0.05, 0.04, 0.03], [0.15, 0.10, 0.06], [0.32, 0.20, 0.10], [0.62, 0.48, 0.28],
                 [0.55, 0.55, 0.55], [0.85, 0.85, 0.85], [0.45, 0.18, 0.08]])
SKIN_LIGHT, SKIN_DARK = np.array([0.97, 0.82, 0.72]), np.array([0.28, 0.18, 0.12])
FEET = [J[n] for n in ("left_ankle", "right_ankle", "left_foot", "right_foot")]
# painted clothes (no garment mesh): a long-sleeved top and long trousers, as body parts
TOP_JOINTS = [J[n] for n in ("spine1", "spine2", "spine3", "left_collar", "right_collar", "left_shoulder",
                             "right_shoulder", "left_elbow", "right_elbow")]
BOTTOM_JOINTS = [J[n] for n in ("pelvis", "left_hip", "right_hip", "left_knee", "right_knee")]


def int_power(x: np.ndarray, k: int) -> np.ndarray:
    """x ** k for a non-negative integer k by repeated squaring (exactly rounded multiplications)."""
    out, base = np.ones_like(x), x.copy()
    while k:
        if k & 1:
            out = out * base
        base, k = base * base, k >> 1
    return out


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """A gamma-2 approximation of the sRGB curve (squares only: exactly rounded)."""
    return c * c


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    return np.sqrt(np.clip(c, 0.0, 1.0))


# ---------------------------------------------------------------------------------------------
# materials

def pattern(rng: np.random.Generator, rest: np.ndarray, photo: np.ndarray | None) -> np.ndarray:
    """Albedo (N, 3) sRGB of one garment from its rest-pose vertices (N, 3), body frame metres."""
    n = len(rest)
    a = PALETTE[rng.integers(len(PALETTE))] * rng.uniform(0.85, 1.15, 3)
    b = PALETTE[rng.integers(len(PALETTE))] * rng.uniform(0.85, 1.15, 3)
    kind = rng.choice(["plain", "plain", "plain", "stripes", "plaid", "checks", "dots", "denim", "print", "blotch"])
    x, y, z = rest[:, 0], rest[:, 1], rest[:, 2]
    if kind == "plain":
        col = np.tile(a, (n, 1))
    elif kind == "stripes":
        period = rng.uniform(0.01, 0.08)
        axis = y if rng.random() < 0.7 else x
        t = np.floor(axis / period + rng.uniform(0, 1)) % 2
        col = np.where(t[:, None] > 0, a, b)
    elif kind in ("plaid", "checks"):
        period = rng.uniform(0.02, 0.10)
        u, v = np.floor(x / period) % 2, np.floor(y / period) % 2
        if kind == "checks":
            col = np.where(((u + v) % 2)[:, None] > 0, a, b)
        else:
            col = a * (0.6 + 0.2 * u[:, None] + 0.2 * v[:, None]) + b * 0.25 * (u * v)[:, None]
    elif kind == "dots":
        period = rng.uniform(0.02, 0.06)
        fu, fv = x / period - np.floor(x / period) - 0.5, y / period - np.floor(y / period) - 0.5
        col = np.where((fu * fu + fv * fv < 0.08)[:, None], b, a)
    elif kind == "denim":
        base = np.array([0.20, 0.28, 0.45]) * rng.uniform(0.7, 1.4)
        col = base * rng.uniform(0.8, 1.15, (n, 1))
    elif kind == "print" and photo is not None:
        h, w = photo.shape[:2]
        s = rng.uniform(0.4, 1.2)  # metres covered by the photo
        u = np.clip(((x + z * 0.3) / s + 0.5) * (w - 1), 0, w - 1).astype(np.int64)
        v = np.clip((0.5 - (y - y.mean()) / s) * (h - 1), 0, h - 1).astype(np.int64)
        col = photo[v, u].astype(np.float64) / 255.0
    else:  # blotch: a few soft spots of the second colour
        col = np.tile(a, (n, 1))
        for _ in range(rng.integers(3, 9)):
            c = rest[rng.integers(n)]
            d2 = ((rest - c) ** 2).sum(1)
            r2 = rng.uniform(0.03, 0.12) ** 2
            m = np.clip(1.0 - d2 / r2, 0.0, 1.0)[:, None]
            col = col * (1 - m) + b * m
    col = col * rng.uniform(0.93, 1.07, (n, 1)) if rng.random() < 0.5 else col  # fabric grain
    return np.clip(col, 0.0, 1.0)


def body_albedo(rng: np.random.Generator, rest: np.ndarray, parts: np.ndarray, joints: np.ndarray,
                face: np.ndarray) -> np.ndarray:
    """Skin of a continuous tone, a face (eyes, brows, lips), hair on the scalp (or none), shoes,
    (V, 3) sRGB; ``rest``: the rest-pose vertices, ``joints``: rest joints (24, 3), ``face``: the
    rest nose, left and right eye (3, 3), body frame (+Y up, +Z forward)."""
    t = rng.random()
    skin = SKIN_LIGHT * (1 - t) + SKIN_DARK * t
    skin = skin * rng.uniform(0.94, 1.06, 3)
    col = np.tile(skin, (len(rest), 1)) * rng.uniform(0.97, 1.03, (len(rest), 1))
    head = J["head"]
    hy, hz = joints[head, 1], joints[head, 2]
    hair = HAIR[rng.integers(len(HAIR))] * rng.uniform(0.85, 1.15)
    on_head = parts == head
    nose, eyes = face[0], face[1:3]
    front = on_head & (rest[:, 2] > nose[2] - 0.05)
    for e in eyes:
        d = rest - e
        col[front & ((d * d).sum(1) < 0.011 ** 2)] = [0.06, 0.05, 0.05]
        brow = front & (np.abs(d[:, 0]) < 0.022) & (d[:, 1] > 0.014) & (d[:, 1] < 0.024)
        col[brow] = hair * 0.7
    d = rest - (nose + [0.0, -0.032, 0.0])
    col[front & ((d[:, 0] / 0.024) ** 2 + (d[:, 1] / 0.008) ** 2 < 1)] = skin * [0.78, 0.45, 0.45]
    if rng.random() < 0.88:
        long_hair = rng.random() < 0.4
        top = on_head & ((rest[:, 1] > hy + 0.04) | ((rest[:, 2] < hz - 0.02) & (rest[:, 1] > hy - 0.05)))
        if long_hair:
            top |= (parts == J["neck"]) & (rest[:, 2] < joints[J["neck"], 2] - 0.01)
        col[top] = hair
    shoes = np.isin(parts, FEET) & (rest[:, 1] < joints[J["left_ankle"], 1] + 0.05)
    col[shoes] = PALETTE[rng.integers(len(PALETTE))] * 0.8
    return np.clip(col, 0.0, 1.0)


# ---------------------------------------------------------------------------------------------
# lighting

def lights(rng: np.random.Generator) -> dict:
    """A key, a fill and a rim light (directions towards the light, OpenCV camera frame) and a
    sky/ground ambient."""
    def direction(az_deg, el_deg):
        az, el = np.radians(az_deg), np.radians(el_deg)
        # camera frame: x right, y down, z forward; az 0 = from the camera's side
        return np.array([np.sin(az) * np.cos(el), -np.sin(el), -np.cos(az) * np.cos(el)])

    warm = rng.uniform(-1, 1)
    tint = np.array([1.0 + 0.12 * warm, 1.0, 1.0 - 0.15 * warm])
    key_az = rng.uniform(-120, 120)
    return {
        "dirs": np.stack([direction(key_az, rng.uniform(15, 70)),
                          direction(key_az - np.sign(key_az or 1) * rng.uniform(60, 120), rng.uniform(-10, 40)),
                          direction(rng.uniform(150, 210), rng.uniform(10, 50))]),
        "colours": np.stack([tint * rng.uniform(0.7, 1.3), np.full(3, rng.uniform(0.1, 0.45)),
                             np.full(3, rng.uniform(0.0, 0.7))]),
        "sky": np.array([0.80, 0.88, 1.0]) * rng.uniform(0.15, 0.45),
        "ground": np.array([0.55, 0.50, 0.45]) * rng.uniform(0.05, 0.25),
        "exposure": rng.uniform(0.8, 1.3),
    }


def shade(points: np.ndarray, normals: np.ndarray, albedo: np.ndarray, spec: np.ndarray, shininess: np.ndarray,
          light: dict) -> np.ndarray:
    """Per-vertex colour (V, 3) sRGB in [0, 1] of vertices (camera frame) with unit normals facing
    the camera, albedo (sRGB), specular strength (V,) and integer shininess (V,)."""
    view = -points / np.sqrt((points * points).sum(1, keepdims=True))
    n = np.where(((normals * view).sum(1) < 0)[:, None], -normals, normals)
    lin = srgb_to_linear(albedo)
    up = -n[:, 1]  # camera y is down
    amb = light["ground"] + (light["sky"] - light["ground"]) * (0.5 + 0.5 * up)[:, None]
    col = lin * amb
    for d, c in zip(light["dirs"], light["colours"], strict=True):
        ndl = np.maximum(n @ d, 0.0)
        h = d + view
        h = h / np.sqrt(np.maximum((h * h).sum(1, keepdims=True), 1e-30))
        ndh = np.maximum((n * h).sum(1), 0.0)
        hl = np.zeros(len(n))
        for s in np.unique(shininess):
            m = shininess == s
            hl[m] = int_power(ndh[m], int(s))
        col = col + c * (lin * ndl[:, None] + (spec * hl * (ndl > 0))[:, None])
    col = col * light["exposure"]
    return linear_to_srgb(col / (1.0 + 0.25 * col))  # a soft shoulder instead of a hard clip


# ---------------------------------------------------------------------------------------------
# the camera

def downsample2(img2: np.ndarray) -> np.ndarray:
    """The 2x2 mean of an (2H, 2W, ...) uint8/int image, rounded (integer arithmetic)."""
    s = img2.astype(np.int32)
    q = s[0::2, 0::2] + s[1::2, 0::2] + s[0::2, 1::2] + s[1::2, 1::2]
    return ((q + 2) // 4).astype(np.uint8)


def composite2(person2: np.ndarray, covered2: np.ndarray, bg: np.ndarray) -> np.ndarray:
    """The anti-aliased frame: each pixel's four sub-samples of the person where covered, the
    background elsewhere (integer arithmetic)."""
    c = covered2.astype(np.int32)
    p = person2.astype(np.int32) * c[..., None]
    psum = p[0::2, 0::2] + p[1::2, 0::2] + p[0::2, 1::2] + p[1::2, 1::2]
    cnt = c[0::2, 0::2] + c[1::2, 0::2] + c[0::2, 1::2] + c[1::2, 1::2]
    return ((psum + (4 - cnt)[..., None] * bg.astype(np.int32) + 2) // 4).astype(np.uint8)


def photo_crop(rng: np.random.Generator, photo: np.ndarray, w: int, h: int) -> np.ndarray:
    """A random crop of ``photo`` with the frame's aspect (30-100 % of its size), flipped at
    random, resized to (h, w) uint8."""
    ph, pw = photo.shape[:2]
    aspect = w / h
    scale = rng.uniform(0.3, 1.0)
    cw = min(pw, ph * aspect) * scale
    ch = cw / aspect
    x0, y0 = rng.uniform(0, pw - cw), rng.uniform(0, ph - ch)
    crop = photo[int(y0):int(y0 + ch), int(x0):int(x0 + cw)]
    interp = cv2.INTER_AREA if crop.shape[1] > w else cv2.INTER_LINEAR
    out = cv2.resize(crop, (w, h), interpolation=interp)
    return np.ascontiguousarray(out[:, ::-1]) if rng.random() < 0.5 else out


def camera_effects(rng: np.random.Generator, img: np.ndarray) -> tuple[np.ndarray, int]:
    """Lens blur, white balance, vignetting and sensor noise on a uint8 frame; the JPEG quality to
    store it at. Returns (frame, quality)."""
    h, w = img.shape[:2]
    out = img
    if rng.random() < 0.3:
        out = cv2.GaussianBlur(out, (0, 0), rng.uniform(0.5, 1.3))
    f = out.astype(np.float32)
    f = f * rng.uniform(0.88, 1.12, 3).astype(np.float32)
    if rng.random() < 0.6:
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / np.float32((w / 2) ** 2 + (h / 2) ** 2)
        f = f * (np.float32(1.0) - np.float32(rng.uniform(0.1, 0.45)) * r2)[..., None]
    gain = np.float32(rng.uniform(0.02, 0.5))
    read = np.float32(rng.uniform(0.5, 3.0))
    sigma = np.sqrt(gain * np.maximum(f, 0) + read * read)
    f = f + sigma * rng.standard_normal(f.shape, dtype=np.float32)
    out = np.clip(np.rint(f), 0, 255).astype(np.uint8)
    return out, int(rng.integers(40, 96))


def jpeg(img: np.ndarray, quality: int) -> bytes:
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(img[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def unjpeg(data: bytes | np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)[..., ::-1])
