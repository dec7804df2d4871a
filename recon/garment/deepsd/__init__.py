"""DeePSD (thesis ch. 4): any outfit mesh to its animation model, no training per outfit.

``model`` is inference; ``data``, ``train`` and ``eval`` make and measure it."""
