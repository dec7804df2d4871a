"""Keypoint sources for the image pipeline: MediaPipe Pose (optional extra) + the learned adapter
from its landmarks to our J+ (24 joints + 18 surface landmarks)."""
from recon.keypoints.mediapipe import MediaPipePose, MPPose, available

__all__ = ["MediaPipePose", "MPPose", "available"]
