"""Video in, one motion per person out: ``recon video`` (``recon.video.run.video``).

``frames`` reads the frames of a video file or a folder of images, with a frame range;
``perframe`` runs the image pipeline on each frame (MediaPipe in video mode), stored batch by
batch; ``camera_motion`` and ``camera_travel`` measure how the camera turned and moved; ``track``
follows people across frames; ``smooth`` optimises each track's motion over all its frames (motion
prior, foot contact); ``ground`` and ``world`` put a clip's tracks on one ground, in one world
frame; ``outputs`` writes BVH, animated .glb, JSON and the overlay video; ``run`` puts them
together.
"""
from __future__ import annotations

from recon.video.frames import Frame, FrameRange, FrameSource, VideoError
from recon.video.run import VideoOptions, VideoResult, video
from recon.video.smooth import SmoothConfig
from recon.video.track import TrackerConfig

__all__ = ["Frame", "FrameRange", "FrameSource", "SmoothConfig", "TrackerConfig", "VideoError", "VideoOptions",
           "VideoResult", "video"]
