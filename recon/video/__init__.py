"""Video input (issue 53, in progress): ``frames`` reads the frames of a video file or a folder of
images, with a frame range; the per-track reconstruction is not built yet."""
from __future__ import annotations

from recon.video.frames import Frame, FrameRange, FrameSource, VideoError

__all__ = ["Frame", "FrameRange", "FrameSource", "VideoError"]
