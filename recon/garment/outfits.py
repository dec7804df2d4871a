"""A distribution of outfits: CLOTH3D's procedural garments (thesis 3.3.2, ``templates``) drawn at
random, the variety DeePSD (thesis ch. 4) and the GCVAE (3.4) learn from.

An outfit is a family (which garments, in which layers) and the parameters of each garment:
sleeve and leg lengths, hem and waist heights, widths, skirt length and flare, the resolution and
the remeshing (midpoint or Loop subdivision, a skirt's ring spacing). Vertex order is shuffled per
outfit by the data generator, so nothing can rely on it.

Held out for testing (never drawn for training or validation): the family ``dress-trousers`` (a
dress over leggings: two layers never seen together) and a band of each of three parameters
(sleeve, leg and skirt lengths). A test outfit is either of the held-out family or has every
banded parameter it uses inside its band.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from recon.garment.templates import GarmentSpec, Width

TRAIN_FAMILIES = ("top", "trousers", "skirt", "top-trousers", "top-skirt", "dress", "jumpsuit")
HELD_OUT_FAMILIES = ("dress-trousers",)
FAMILIES = TRAIN_FAMILIES + HELD_OUT_FAMILIES

RANGES = {
    "sleeve": (0.0, 0.9),  # fraction of the arm; below 0.05: sleeveless
    "leg": (0.25, 1.0),  # fraction of the leg
    "skirt_length": (0.25, 0.75),  # metres below the waist
    "flare": (0.08, 0.6),
    "hem": (-0.12, 0.06),  # a top's hem above the pelvis joint (m)
    "dress_hem": (0.05, 0.15),  # a dress's bodice hem
    "waist": (0.0, 0.1),
    "torso_w0": (0.006, 0.035),  # ease of the torso (m)
    "limb_w0": (0.01, 0.04),  # ease of sleeves and legs at the shoulder/hip
    "limb_a2": (0.0, 0.12),  # widening past the elbow/knee (m per m)
    "subdivide_above": (0.03, 0.05),  # resolution: median edge at most this (m)
    "skirt_step": (0.01, 0.018),
}
HELD_OUT_BANDS = {"sleeve": (0.45, 0.58), "leg": (0.55, 0.68), "skirt_length": (0.48, 0.56)}
LOOP_REMESH = 0.3  # share of garments remeshed by Loop subdivision


class OutfitSampler:
    """``OutfitSampler(held_out)(rng) -> (family, [GarmentSpec])``: train/val outfits
    (``held_out=False``) or test outfits (``held_out=True``)."""

    def __init__(self, held_out: bool = False):
        self.held_out = held_out

    def value(self, rng: np.random.Generator, name: str, band: bool) -> float:
        lo, hi = RANGES[name]
        if name in HELD_OUT_BANDS:
            b_lo, b_hi = HELD_OUT_BANDS[name]
            if band:
                return float(rng.uniform(b_lo, b_hi))
            while True:  # outside the band: the train/val distribution
                x = float(rng.uniform(lo, hi))
                if not b_lo <= x <= b_hi:
                    return x
        return float(rng.uniform(lo, hi))

    def __call__(self, rng: np.random.Generator) -> tuple[str, list[GarmentSpec]]:
        if self.held_out and rng.random() < 0.5:
            family, band = HELD_OUT_FAMILIES[int(rng.integers(len(HELD_OUT_FAMILIES)))], False
        else:
            family, band = TRAIN_FAMILIES[int(rng.integers(len(TRAIN_FAMILIES)))], self.held_out
        v = lambda name: self.value(rng, name, band)  # noqa: E731
        sub = v("subdivide_above")
        loop = rng.random() < LOOP_REMESH
        common = dict(subdivide_above=2 * sub if loop else sub, remesh="loop" if loop else "midpoint",
                      torso=Width(v("torso_w0")), limb=Width(v("limb_w0"), -0.02, v("limb_a2"), 0.3))
        sleeve = v("sleeve")
        sleeve = 0.0 if sleeve < 0.05 else sleeve
        top = GarmentSpec("top", "top", sleeve=sleeve, hem=v("hem"), **common)
        trousers = GarmentSpec("trousers", "trousers", leg=v("leg"), waist=v("waist"), **common)
        skirt = GarmentSpec("skirt", "skirt", skirt_length=v("skirt_length"), skirt_flare=v("flare"),
                            waist=max(v("waist"), 0.03), skirt_step=v("skirt_step"), **common)
        dress = GarmentSpec("dress", "dress", sleeve=min(sleeve, 0.6), hem=v("dress_hem"),
                            skirt_length=v("skirt_length") + 0.1, skirt_flare=v("flare"),
                            skirt_step=v("skirt_step"), **common)
        jumpsuit = GarmentSpec("jumpsuit", "jumpsuit", sleeve=sleeve, leg=v("leg"), **common)
        if family == "top-skirt":  # a top over the skirt or tucked into it
            tucked = rng.random() < 0.5
            specs = [_layer(skirt, 1 if tucked else 0), _layer(top, 0 if tucked else 1)]
        elif family == "top-trousers":
            specs = [_layer(trousers, 0), _layer(top, 1)]
        elif family == "dress-trousers":
            specs = [_layer(trousers, 0), _layer(dress, 1)]
        else:
            specs = [{"top": top, "trousers": trousers, "skirt": skirt, "dress": dress, "jumpsuit": jumpsuit}[family]]
        return family, specs


def _layer(spec: GarmentSpec, layer: int) -> GarmentSpec:
    return replace(spec, layer=layer)
