"""Procedural outfits (CLOTH3D) and PBNS neural simulation (thesis ch. 3, 5). Not built yet: issue 6."""
