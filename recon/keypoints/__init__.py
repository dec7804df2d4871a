"""Keypoint sources of the image pipeline: ``source(rgb, K) -> Keypoints | None``.

``base`` (what a source returns), ``adapter`` (the learned map from MediaPipe's landmarks,
``recon.people.mediapipe``, to our J+), ``sources`` (``MediaPipeSource``,
``BackboneSource``), ``train`` (collecting MediaPipe's output on renders and training the
adapter).
"""
from __future__ import annotations

from recon.body.base import BodyModel
from recon.errors import ReconError
from recon.keypoints.base import Keypoints, KeypointSource
from recon.keypoints.sources import BackboneSource, MediaPipeSource
from recon.people.mediapipe import DEFAULT_MODEL, MediaPipePose, MPPose, available

SOURCES = ("mediapipe", "backbone")


def make_source(name: str = "mediapipe", body: BodyModel | None = None, device: str = "cpu", flip: bool | None = None,
                retry: bool = True, guard: bool = True, keypoint_model: str = DEFAULT_MODEL,
                fallback: bool = False, backbone_weight: float = 0.0, search: bool = False,
                detect: bool = False, movenet: float = 0.0, multipose: bool = False) -> KeypointSource:
    """Keypoint source by name: "mediapipe" (default) or "backbone". ``flip`` (test-time mirror
    averaging, see each source): None = the source's default, on for MediaPipe (cheap next to
    the fit), off for the backbone (its 100 ms latency goal). ``retry``: MediaPipe's retries on
    other views when it finds nobody; ``guard``: refuse MediaPipe's phantoms; ``keypoint_model``:
    MediaPipe's landmark model, "lite", "full" or "heavy"; ``fallback``: our backbone where MediaPipe
    finds nobody; ``backbone_weight``: its share of the J+ of MediaPipe's people; ``search``: look for
    people its detector misses without a face (``recon.people.search``); ``detect``: find people
    with the people stage's detector first (``recon.people``); ``movenet``: MoveNet's weight in the 2D
    keypoints of each detected person; ``multipose``: MoveNet MultiPose's boxes too where NanoDet's give
    nobody or more than one person is wanted (all ``MediaPipeSource``)."""
    if name == "mediapipe":
        return MediaPipeSource(flip=True if flip is None else flip, retry=retry, guard=guard, model=keypoint_model,
                               fallback=fallback, backbone_weight=backbone_weight, search=search,
                               detect=detect, movenet=movenet, multipose=multipose)
    if name == "backbone":
        return BackboneSource(body, device=device, flip=bool(flip))
    raise ReconError(f"unknown keypoint source {name!r}; choose one of {', '.join(SOURCES)}")


__all__ = ["SOURCES", "BackboneSource", "Keypoints", "KeypointSource", "MPPose", "MediaPipePose", "MediaPipeSource",
           "available", "make_source"]
