"""Keyframe authoring of garment animation in a learned intrinsic garment space.

``model`` is inference; ``data``, ``train`` and ``eval`` make and measure it."""
