"""Keypoint sources for the frames of one video, in order.

``MediaPipeVideoSource`` (one person): MediaPipe in its video mode; where it finds nobody, every
``SEARCH_EVERY``-th such frame (every one after a find) is searched as ``recon run`` searches a
photo, with its retries on padded and mirrored views (people entering the frame, cut by it).

``MediaPipeVideoSource(rgb, K) -> Keypoints | None`` like ``MediaPipeSource``, but MediaPipe
follows the person from the previous frame's landmarks and runs its person detector only when
it has lost them: one landmark-model call a frame (no mirror pass, no retries, no backbone), and
landmarks that MediaPipe filters over time. One person: MediaPipe's video mode follows one.
The guard still refuses answers it takes for phantoms; ``backbone_weight`` blends our backbone's
J+ in where it is confident, as ``MediaPipeSource`` does; after ``PROBE_MISSES`` frames in a row
where it was not, it is asked again only ``PROBE_EVERY`` frames later (on real footage it never
is: its cost would buy nothing).

``PeopleVideoSource`` (several people): each person found in the last frame is looked for on a
crop around where they were (there MediaPipe sees them large, and one at a time); the whole frame,
with the people followed painted out, is searched for newcomers (``MediaPipeSource.people``, with
the people stage's detector where ``detect``) when someone was lost and every ``search_every`` frames.
"""
from __future__ import annotations

import numpy as np

from recon.keypoints.adapter import KeypointAdapter
from recon.keypoints.base import Keypoints
from recon.keypoints.sources import TRUSTED_CONFIDENCE, BackboneSource, MediaPipeSource, blend_backbone
from recon.keypoints.views import blank_person, same_person, windows
from recon.people import guard as person_guard
from recon.people.boxes import box_iou
from recon.people.mediapipe import DEFAULT_MODEL, MediaPipePose

PROBE_MISSES, PROBE_EVERY = 3, 30
SEARCH_EVERY = 3


class MediaPipeVideoSource:
    """One person per frame, frames of one video in order (a new video needs a new source).
    ``model``: MediaPipe's landmark model; ``guard``: refuse answers scored as phantoms."""

    name = "mediapipe-video"

    def __init__(self, model: str = DEFAULT_MODEL, guard: bool = True, backbone_weight: float = 0.0,
                 adapter_path=None):
        self.mp = MediaPipePose(model, video=True)
        self.model = self.mp.model
        self.adapter = KeypointAdapter.load(adapter_path, self.model)
        self.guard = guard
        self.person_guard = person_guard.for_model(self.model)
        self.backbone_weight = backbone_weight
        self._backbone: BackboneSource | None = None
        self._frame, self._misses, self._next_probe, self._empty = 0, 0, 0, 0
        self._search: MediaPipeSource | None = None
        self._searched = False

    def _find(self, rgb: np.ndarray, k: np.ndarray) -> Keypoints | None:
        r = self.mp(rgb)
        if r is not None:
            ev = person_guard.evidence(r, rgb.shape)
            if not self.guard or self.person_guard.accept(ev):
                self._empty = 0
                p3, uv = self.adapter.predict(r, k)
                return Keypoints(p3, uv, float(np.mean(r.visibility)), r.box(), r.mask, self.person_guard.score(ev),
                                 "mediapipe")
        self._empty += 1
        if self._empty % SEARCH_EVERY != 1 and not self._searched:
            return None
        if self._search is None:
            self._search = MediaPipeSource(flip=False, retry=True, guard=self.guard, model=self.model)
        kp = self._search(rgb, k)
        self._searched = kp is not None  # found so: searched again next frame while video mode misses
        return kp

    def __call__(self, rgb: np.ndarray, k: np.ndarray) -> Keypoints | None:
        self._frame += 1
        kp = self._find(rgb, k)
        if kp is None:
            return None
        if not self.backbone_weight or self._frame < self._next_probe:
            return kp
        if self._backbone is None:
            self._backbone = BackboneSource(min_confidence=TRUSTED_CONFIDENCE)
        blended = blend_backbone(self._backbone, rgb, k, kp, self.backbone_weight)
        self._misses = 0 if blended is not kp else self._misses + 1
        if self._misses >= PROBE_MISSES:
            self._misses, self._next_probe = 0, self._frame + PROBE_EVERY
        return blended

    def close(self) -> None:
        self.mp.close()


class PeopleVideoSource:
    """Up to ``max_people`` people per frame (``people(rgb, K, n)``), frames of one video in order;
    options as ``MediaPipeSource``'s (no mirror pass: the crops cost one MediaPipe call a person)."""

    name = "mediapipe-people-video"

    def __init__(self, model: str = DEFAULT_MODEL, guard: bool = True, backbone_weight: float = 0.0,
                 search_every: int = 10, margin: float = 0.4, keep_lost: int = 15, detect: bool = False):
        self.source = MediaPipeSource(flip=False, retry=True, guard=guard, model=model,
                                      backbone_weight=backbone_weight, detect=detect)
        self.model = self.source.model
        self.search_every, self.margin, self.keep_lost = search_every, margin, keep_lost
        # where each person was last seen: [box (4,), velocity (4,) a frame, frames since seen]
        self.followed: list[list] = []
        self._frame = 0

    def __call__(self, rgb: np.ndarray, k: np.ndarray) -> Keypoints | None:
        found = self.people(rgb, k, 1)
        return found[0] if found else None

    def _on_crop(self, full: np.ndarray, rgb: np.ndarray, k: np.ndarray, box, found: list[Keypoints]
                 ) -> Keypoints | None:
        """The person MediaPipe finds on a square crop of ``rgb`` (the frame ``full`` with the people
        found so far painted over) around ``box`` (grown by ``margin``), none of ``found``."""
        h, w = rgb.shape[:2]
        cx, cy = 0.5 * (box[0] + box[2]), 0.5 * (box[1] + box[3])
        half = 0.5 * (1 + self.margin) * max(box[2] - box[0], box[3] - box[1], 16.0)
        x0, y0 = int(max(0, cx - half)), int(max(0, cy - half))
        x1, y1 = int(min(w, cx + half)), int(min(h, cy + half))
        if x1 - x0 < 16 or y1 - y0 < 16:
            return None
        return self.source.person_in(full, k, (x0, y0, x1, y1), painted=rgb, found=found)

    def people(self, rgb: np.ndarray, k: np.ndarray, max_people: int) -> list[Keypoints]:
        self._frame += 1
        found: list[Keypoints] = []
        work = rgb
        followed = []
        for box, velocity, missed in self.followed[:max_people]:
            # where they should be now: a person hidden a while (walking behind another) moves on
            kp = self._on_crop(rgb, work, k, box + velocity * (missed + 1), found)
            if kp is not None:
                found.append(kp)
                work = blank_person(work, kp)
                new_box = np.asarray(kp.box, float)
                followed.append([new_box, 0.5 * velocity + 0.5 * (new_box - box) / (missed + 1), 0])
            elif missed < self.keep_lost:
                followed.append([box, velocity, missed + 1])
        lost = any(f[2] for f in followed)
        if len(found) < max_people and (lost or not followed or self._frame % self.search_every == 1):
            new = self.source.people(work, k, max_people - len(found))
            for kp in new:
                if not any(same_person(kp, f) for f in found):
                    found.append(kp)
                    work = blank_person(work, kp)
            if not new:  # nobody in the whole frame: small people are found on windows of it
                new = self._windows(rgb, work, k, max_people - len(found), found)
                found += new
            for kp in new:  # newcomers, unless they are someone followed who was hidden
                box = np.asarray(kp.box, float)
                hidden = next((f for f in followed if f[2] and box_iou(f[0] + f[1] * f[2], box) > 0.3), None)
                if hidden is None:
                    followed.append([box, np.zeros(4), 0])
                else:
                    hidden[0], hidden[2] = box, 0
        self.followed = followed
        return found

    def _windows(self, rgb: np.ndarray, work: np.ndarray, k: np.ndarray, n: int, found: list[Keypoints]
                 ) -> list[Keypoints]:
        """Up to ``n`` people on the windows of ``MediaPipeSource.people`` (answers need the guard's
        stricter evidence: a window is an upscaled view)."""
        new: list[Keypoints] = []
        for x0, y0, x1, y1 in windows(*work.shape[:2]):
            if len(new) >= n:
                break
            kp = self.source.person_in(rgb, k, (x0, y0, x1, y1), strict=True, painted=work, found=found + new)
            if kp is not None:
                new.append(kp)
                work = blank_person(work, kp)
        return new
