"""Poses: mocap readers, retargeting to the canonical skeleton, cached pose set and samplers."""
