"""Drawing bodies and clothes: the fast offscreen rasteriser (``raster``: RGB, part labels and
depth in one pass, the same bits on every x86-64 CPU), the other domain's shaded look (``look``)
and mesh normals (``normals``). The synthetic benchmarks, the overlays of ``recon run`` and
``recon video`` and the results page draw with it; it imports nothing of theirs.
"""
