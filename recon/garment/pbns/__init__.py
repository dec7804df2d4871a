"""PBNS (thesis ch. 5): an outfit's pose-space deformation, trained without simulation data.

``model`` is inference; ``data``, ``train`` and ``eval`` make and measure it."""
