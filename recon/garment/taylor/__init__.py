"""Example-based synthesis: the body-shape dimension by Taylor expansions at anchor poses.

``model`` is inference; ``data``, ``train`` and ``eval`` make and measure it."""
