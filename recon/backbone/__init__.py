"""Volumetric-heatmap stacked-hourglass CNN (thesis ch. 2.4.1).

``hourglass.py`` (the network, CPU and GPU sizes), ``efficientnet.py`` (an ImageNet-initialisable
stem), ``volumetric.py`` (soft-argmax and the softmax cross-entropy on volumetric heatmaps),
``crop.py`` (the metric 2.5 m crop and the grid <-> camera-frame mapping), ``model.py``
(inference on crops: ``Backbone``), ``search.py`` (finding the crop without ground truth),
``train.py`` (training on ``recon synth`` shards or online renders; export). Shipped weights:
``weights/hourglass_base.pt`` (see its MODEL_CARD.md).
"""
