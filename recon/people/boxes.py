"""Box geometry of the people stage: (x0, y0, x1, y1) boxes in pixels, their overlaps."""
from __future__ import annotations


def box_area(b) -> float:
    return (b[2] - b[0]) * (b[3] - b[1])


def box_intersection(a, b) -> float:
    return max(0.0, min(a[2], b[2]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[1], b[1]))


def box_iou(a, b) -> float:
    """Intersection over union of two (x0, y0, x1, y1) boxes."""
    inter = box_intersection(a, b)
    union = box_area(a) + box_area(b) - inter
    return float(inter / union) if union > 0 else 0.0


def box_overlap(a, b) -> float:
    """The share of the smaller of two boxes that lies inside the other (1: one contains the
    other; a person found again from a leftover limb overlaps its first box this way)."""
    small = min(box_area(a), box_area(b))
    return float(box_intersection(a, b) / small) if small > 0 else 0.0
