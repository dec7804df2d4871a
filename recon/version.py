"""recon's version (also ``recon.__version__``; pyproject.toml holds the same)."""
__version__ = "0.4.0"
