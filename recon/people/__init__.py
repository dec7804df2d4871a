"""The people stage: where every person in an image is, before anyone's keypoints.

``detector`` (``PersonDetector``: NanoDet over the whole image and zoomed tiles, NMS),
``multipose`` (``MultiPoseDetector``: MoveNet MultiPose, a second source of boxes),
``mediapipe`` (MediaPipe Pose: its face-anchored detector and its landmark model, which also
says whether a region holds a person), ``search`` (``PersonSearch``: people MediaPipe's detector
misses, found without a face), ``guard`` (the rule that refuses MediaPipe's phantom bodies),
``boxes`` (box geometry), ``tfjs`` (TF.js graph models run in torch, no TensorFlow), ``models``
(where set-up installs the shipped models). ``recon.keypoints`` reads each person found into our
J+ (several people in one image: ``MediaPipeSource.people``).
"""
from __future__ import annotations

from recon.people.detector import Detection, PersonDetector
from recon.people.multipose import MultiPoseDetector

__all__ = ["Detection", "MultiPoseDetector", "PersonDetector"]
