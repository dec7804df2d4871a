"""The results page of an output folder (``index.html``), which works offline from the file
system: ``write_page`` / ``try_write_page`` (recon.page.build), its 3D models
(recon.page.models), a headless Chromium to check it (recon.page.chromium)."""
from recon.page.build import folder_kind, open_in_browser, try_write_page, viewer_installed, write_page

__all__ = ["folder_kind", "open_in_browser", "try_write_page", "viewer_installed", "write_page"]
