"""Volumetric-heatmap stacked-hourglass CNN (thesis ch. 2.4.1).

``hourglass.py`` (the network, CPU and GPU sizes), ``volumetric.py`` (soft-argmax and the
softmax cross-entropy on volumetric heatmaps), ``crop.py`` (the metric 2.5 m crop and the
grid <-> camera-frame mapping), ``train.py`` (training on ``recon synth`` shards). No trained
weights ship yet (issue 5).
"""
