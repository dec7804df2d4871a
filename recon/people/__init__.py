"""The people stage: where every person in an image is, before anyone's keypoints.

``detector`` (``PersonDetector``: NanoDet over the whole image and zoomed tiles, NMS),
``multipose`` (``MultiPoseDetector``: MoveNet MultiPose, a second source of boxes), ``boxes``
(their geometry), ``tfjs`` (TF.js graph models run in torch, no TensorFlow), ``models`` (where
set-up installs the shipped models). ``recon.keypoints`` reads each person on its box.
"""
from __future__ import annotations

from recon.people.detector import Detection, PersonDetector
from recon.people.multipose import MultiPoseDetector

__all__ = ["Detection", "MultiPoseDetector", "PersonDetector"]
