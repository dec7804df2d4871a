"""DeePSD as a garment model (thesis ch. 4): any outfit animated without training, its blend
weights and pose-space blend shapes predicted from the template mesh, then dressed as PBNS is
(resized by transfer, quasi-static). What a garment mesh with no PBNS weights of its own gets."""
from __future__ import annotations

from pathlib import Path

from recon.body import default_body
from recon.garment import store
from recon.garment.deepsd.model import animation_model
from recon.garment.pbns.garment_model import BlendGarment


class DeePSDGarment(BlendGarment):
    """``outfit``: a preset or a garment mesh's path (``path`` is not used: nothing is trained)."""

    name = "deepsd"
    static = True

    def __init__(self, outfit: str, path: str | Path | None = None, resizer: bool = True,
                 dynamics: bool | None = None):
        store.check_outfit(outfit)
        model, ck = animation_model(default_body(), outfit)
        self.outfit = str(Path(outfit).resolve()) if Path(outfit).is_file() else outfit  # found from anywhere
        self._take(model, ck, None)

    @property
    def label(self) -> str:
        return "DeePSD"
