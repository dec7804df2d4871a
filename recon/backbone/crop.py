"""The thesis' metric crop: a 2.5 x 2.5 m square, centred on the mean joint and facing the
camera, projected into the image, defines the crop; depth is binned over +-1.25 m around the
centre. Volumetric grid coordinates g = (gx, gy, gz) in [0, 1]^3 then map to camera space:
    u = u0 + gx * side,  v = v0 + gy * side,  Z = Zc + (gz - 0.5) * extent,
    X = (u - cx) Z / fx,  Y = (v - cy) Z / fy          (OpenCV camera, metres).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from recon import camera

EXTENT_M = 2.5


@dataclass
class Crop:
    u0: float
    v0: float
    side: float  # pixels
    zc: float  # metres, depth of the crop centre
    k: np.ndarray  # (3, 3) intrinsics of the full image
    extent: float = EXTENT_M

    @classmethod
    def around(cls, centre: np.ndarray, k: np.ndarray, extent: float = EXTENT_M) -> Crop:
        """Crop around a camera-frame centre (e.g. the mean of the joints)."""
        uc, vc = camera.project(np.asarray(centre, dtype=np.float64)[None], k)[0]
        side = k[0, 0] * extent / centre[2]
        return cls(uc - side / 2, vc - side / 2, side, float(centre[2]), k, extent)

    def image(self, rgb: np.ndarray, size: int, border=(0, 0, 0)) -> np.ndarray:
        """Resample the crop to (size, size); outside the image is filled with ``border``."""
        s = size / self.side
        m = np.array([[s, 0, -self.u0 * s], [0, s, -self.v0 * s]], dtype=np.float64)
        return cv2.warpAffine(rgb, m, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                              borderValue=border)

    def to_grid(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) camera-frame points -> (N, 3) grid coordinates in [0, 1] (inside the volume)."""
        uv = camera.project(points, self.k)
        return np.stack([(uv[:, 0] - self.u0) / self.side, (uv[:, 1] - self.v0) / self.side,
                         (points[:, 2] - self.zc) / self.extent + 0.5], axis=1)

    def from_grid(self, grid: np.ndarray) -> np.ndarray:
        """Inverse of ``to_grid``."""
        return camera.unproject(self.pixels(grid), self.zc + (grid[:, 2] - 0.5) * self.extent, self.k)

    def pixels(self, grid: np.ndarray) -> np.ndarray:
        """(N, 3) grid coordinates -> (N, 2) pixels of the full image."""
        return np.stack([self.u0 + grid[:, 0] * self.side, self.v0 + grid[:, 1] * self.side], axis=1)


def grid_to_camera(grid: torch.Tensor, crop_vec: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    """Batched, differentiable ``Crop.from_grid``: grid (B, P, 3), crop vectors (B, 5) =
    (u0, v0, side, zc, extent) and intrinsics (B, 3, 3) -> camera-frame points (B, P, 3)."""
    u0, v0, side, zc, extent = (crop_vec[:, i, None] for i in range(5))
    uv = torch.stack([u0 + grid[..., 0] * side, v0 + grid[..., 1] * side], -1)
    return camera.unproject(uv, zc + (grid[..., 2] - 0.5) * extent, k)
