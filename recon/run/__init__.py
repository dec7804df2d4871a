"""``recon run``: reconstruct every image of files/folders into an output folder
(``recon.run.batch.run``; the worker in ``worker``, the files of an image in ``files``)."""
from __future__ import annotations

from recon.run.batch import STAGING, RunSummary, check_writable, made_from, recorded, run
from recon.run.worker import Job, Outcome, RunOptions, RunWorker

__all__ = ["STAGING", "Job", "Outcome", "RunOptions", "RunSummary", "RunWorker", "check_writable", "made_from",
           "recorded", "run"]
