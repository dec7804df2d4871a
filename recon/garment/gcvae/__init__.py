"""The GCVAE garment space (thesis 3.4): encode, decode, sample and interpolate garments.

``model`` is inference; ``data``, ``train`` and ``eval`` make and measure it."""
