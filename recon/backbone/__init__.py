"""Volumetric-heatmap stacked-hourglass CNN (thesis ch. 2.4.1) - building blocks.

Not trained yet (issue 5): ``hourglass.py`` (the network), ``volumetric.py`` (soft-argmax and
the softmax cross-entropy on volumetric heatmaps), ``crop.py`` (the metric 2.5 m crop and the
grid <-> camera-frame coordinate mapping).
"""
