"""recon's version: ``recon.__version__``, and pyproject.toml reads it from here."""
__version__ = "0.34.0"
