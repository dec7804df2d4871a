"""The one exception type for problems the user can fix.

``ReconError`` means: bad input (an unreadable image, a file that is not a body model, a flag
that does not apply), a missing file or trained weights, or a missing optional package. Its
message says what is wrong and what to do. The command line prints it without a traceback and
exits with status 2; every other exception is a bug and keeps its traceback.
"""
from __future__ import annotations


class ReconError(Exception):
    """A problem with the user's input, files or environment; the message says what to do."""


class MissingFile(ReconError, FileNotFoundError):
    """A file recon needs (weights, a cache, a data set) is not there; the message names the
    command that makes it."""
