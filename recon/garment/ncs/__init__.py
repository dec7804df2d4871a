"""Neural Cloth Simulation (thesis ch. 6): PBNS with dynamics, taught by the cloth integrator.

``model`` is inference; ``data``, ``train`` and ``eval`` make and measure it."""
