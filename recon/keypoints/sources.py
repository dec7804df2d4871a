"""The image pipeline's keypoint sources: ``source(rgb, K) -> Keypoints | None``.

``MediaPipeSource`` (the default): MediaPipe Pose finds the person and its 33 landmarks and
person mask, the learned adapter maps the landmarks to our J+; our backbone, where it is
confident, answers where MediaPipe finds nobody (``fallback``) and takes a share of each person's
J+ (``backbone_weight``). ``BackboneSource``: our volumetric hourglass alone, which finds its own
crop (``recon.backbone.search``); trained on synthetic renders only.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import cv2
import numpy as np

from recon import camera
from recon.backbone.search import CropSearch, crop_from_keypoints
from recon.body.base import BodyModel
from recon.keypoints.adapter import KeypointAdapter
from recon.keypoints.base import Keypoints
from recon.keypoints.on_boxes import LandmarksOnBoxes
from recon.keypoints.views import (
    GRAY_SMALL,
    blank_person,
    is_grayscale,
    mirrored_camera,
    pad_image,
    same_answer,
    same_person,
    scaled,
    shifted,
    tinted,
    unmirror,
    unview,
    windows,
)
from recon.people import guard as person_guard
from recon.people.detector import PersonDetector
from recon.people.mediapipe import DEFAULT_MODEL, MediaPipePose, MPPose
from recon.people.multipose import MultiPoseDetector, new_boxes
from recon.people.search import MIN_SCORE, PersonSearch

# When MediaPipe finds nobody, it is asked again on these views of the image, in order (view,
# zero-padding factor, detection threshold): its detector misses people behind occluders or cut by
# the frame. Chosen on synth-val (eval/results/error-budget.md, section 3); the default threshold
# is 0.5.
RETRIES = (("plain", 2.0, 0.5), ("plain", 1.5, 0.3), ("mirror", 1.5, 0.5), ("plain", 1.0, 0.3))
# The backbone's mean peak confidence from which recon run trusts it (the fallback's answers, the
# blend): above every person-free image's and far above photos', where it fails (it learnt our
# renders). Chosen on synth-val (eval/results/backbone-fallback.md, source-blend.md).
TRUSTED_CONFIDENCE = 0.65


def blend_backbone(backbone: BackboneSource, rgb: np.ndarray, k: np.ndarray, kp: Keypoints, weight: float
                   ) -> Keypoints:
    """``kp``'s J+ as ``weight`` x the backbone's on its crop + the rest of its own, where the backbone
    is confident (``TRUSTED_CONFIDENCE``); else ``kp`` as it is."""
    b = backbone.on_crop(rgb, k, kp)
    if b.confidence < TRUSTED_CONFIDENCE:
        return kp
    return replace(kp, points3d=(1 - weight) * kp.points3d + weight * b.points3d,
                   points2d=(1 - weight) * kp.points2d + weight * b.points2d, found_by=f"{kp.found_by}+{b.found_by}")


class MediaPipeSource:
    """MediaPipe Pose landmarks -> our J+ via the learned adapter (recon.keypoints.adapter).
    ``flip``: also run on the mirrored image and average the two J+ (mirrored back, left and
    right swapped), unless the mirrored run finds nobody or someone else: one more MediaPipe call
    (its gain: eval/results/pipeline-fit-choices.md; its cost: eval/results/bench-pipeline.md).
    ``retry``: when MediaPipe finds nobody, ask it again on the views of ``RETRIES`` (only then:
    no cost on images where it finds the person at once). ``guard``: refuse answers that
    ``recon.people.guard`` takes for phantoms (as if MediaPipe had found nobody there).
    ``people(rgb, K, n)``: up to n people, one after the other. ``model``: MediaPipe's landmark
    model (``recon.people.mediapipe.MODELS``). Our backbone (``BackboneSource``, loaded at its
    first use) where it is confident (mean peak confidence >= ``TRUSTED_CONFIDENCE``; on photos it
    stays far lower: it learnt our renders): ``fallback``: where MediaPipe finds nobody, its own
    crop search answers instead (people behind occluders; no person mask); ``backbone_weight``:
    each person's J+ become that weight of the backbone's on MediaPipe's crop (``on_crop``) plus
    the rest of MediaPipe's (``found_by`` "mediapipe+backbone"). ``detect``: the people stage's
    boxes first (``detected``); ``multipose``: MoveNet MultiPose's boxes too, where NanoDet's give
    nobody or more than one person is wanted (``recon.people.multipose``). ``last_view`` says which view (or
    "backbone") found the person of the last call."""

    name = "mediapipe"

    def __init__(self, adapter_path=None, flip: bool = True, retry: bool = True, guard: bool = True,
                 model: str = DEFAULT_MODEL, fallback: bool = False, backbone_weight: float = 0.0,
                 search: bool = False, detect: bool = False, movenet: float = 0.0, multipose: bool = False):
        self.mp = MediaPipePose(model)
        self.model = self.mp.model  # the model that runs (full when the file asked for is missing)
        self.adapter = KeypointAdapter.load(adapter_path, self.model)
        self.flip, self.retry, self.guard = flip, retry, guard
        self.person_guard = person_guard.for_model(self.model)  # fitted on this landmark model's answers
        self._by_threshold = {0.5: self.mp}
        self.last_view = None  # which view found the person in the last call (None: nobody)
        self.fallback, self.backbone_weight = fallback, backbone_weight
        self._backbone: BackboneSource | None = None
        self.search = search
        self._searcher: PersonSearch | None = None
        self.detect, self.movenet, self.multipose = detect, movenet, multipose
        self._boxes: PersonDetector | None = None
        self._multipose: MultiPoseDetector | None = None
        self._on_boxes: LandmarksOnBoxes | None = None

    def detected(self, rgb: np.ndarray, k: np.ndarray, max_people: int) -> list[Keypoints]:
        """Up to ``max_people`` people from the people stage's boxes (``recon.people``), best box
        first, each read by the landmark model on its box (``LandmarksOnBoxes``). With
        ``multipose``, MoveNet MultiPose's boxes follow: in crowds (more than one person wanted)
        those that overlap none of NanoDet's, and all of them where NanoDet's give nobody."""
        if self._boxes is None:
            self._boxes = PersonDetector()
            self._on_boxes = LandmarksOnBoxes(self.adapter, self.model, self.flip, self.guard, movenet=self.movenet)
        boxes = self._boxes(rgb)
        found = self._read_boxes(rgb, k, boxes, [], max_people)
        if self.multipose and len(found) < max_people and (max_people > 1 or not found):
            if self._multipose is None:
                self._multipose = MultiPoseDetector()
            more = self._multipose(rgb)
            found = self._read_boxes(rgb, k, new_boxes(more, boxes) if found else more, found, max_people)
        return found

    def _read_boxes(self, rgb: np.ndarray, k: np.ndarray, boxes: list, found: list[Keypoints], max_people: int
                    ) -> list[Keypoints]:
        """``found`` and the people read on ``boxes`` that are no one already found."""
        found = list(found)
        for det in boxes:
            if len(found) >= max_people:
                break
            kp = self._on_boxes(rgb, k, det.box, det.score, first=not found, view=det.view)
            if kp is not None and not any(same_answer(kp, f) for f in found):
                kp.found_by = f"{self.name}-{det.view}"
                found.append(self._with_backbone(rgb, k, kp))
                self.last_view = "detector"
        return found

    @property
    def searcher(self) -> PersonSearch:
        if self._searcher is None:
            self._searcher = PersonSearch(self.model, min_score=MIN_SCORE if self.guard else -np.inf)
        return self._searcher

    def _search(self, rgb: np.ndarray, k: np.ndarray) -> Keypoints | None:
        """A person the detector missed, found without a face (``PersonSearch``), or None."""
        found = self.searcher(rgb)
        if found is None:
            return None
        r, score = found
        p3, uv = self.adapter.predict(r, k)
        self.last_view = "search"
        return Keypoints(p3, uv, float(np.mean(r.visibility)), r.box(), r.mask, score, self.name + "-search")

    @property
    def backbone(self) -> BackboneSource:
        if self._backbone is None:
            self._backbone = BackboneSource(min_confidence=TRUSTED_CONFIDENCE)
        return self._backbone

    def _fallback(self, rgb: np.ndarray, k: np.ndarray) -> Keypoints | None:
        """The backbone's answer when it is confident enough (``fallback``), else None."""
        if not self.fallback:
            return None
        kp = self.backbone(rgb, k)
        self.last_view = None if kp is None else "backbone"
        return kp

    def _with_backbone(self, rgb: np.ndarray, k: np.ndarray, kp: Keypoints) -> Keypoints:
        """A MediaPipe person's J+ blended with the backbone's on its crop (``backbone_weight``)
        where the backbone is confident, else as they are."""
        if not self.backbone_weight or kp.found_by != self.name:
            return kp
        return blend_backbone(self.backbone, rgb, k, kp, self.backbone_weight)

    def _detector(self, threshold: float) -> MediaPipePose:
        if threshold not in self._by_threshold:
            self._by_threshold[threshold] = MediaPipePose(self.model, min_confidence=threshold)
        return self._by_threshold[threshold]

    def _detect(self, rgb: np.ndarray, k: np.ndarray):
        r = self.mp(rgb)
        return None if r is None else (r, *self.adapter.predict(r, k))

    def _person(self, r: MPPose, rgb: np.ndarray, retry: bool) -> float | None:
        """The guard's score of an answer, None when the guard refuses it (a phantom). ``retry``:
        the answer needs a retry view's evidence."""
        ev = person_guard.evidence(r, rgb.shape)
        s = self.person_guard.score(ev)
        if not self.guard or self.person_guard.accept(ev, retry):
            return s
        if retry and s >= self.person_guard.threshold["confirmed"] and self._confirmed(rgb, r):
            return s
        return None

    def _confirmed(self, rgb: np.ndarray, r: MPPose) -> bool:
        """MediaPipe, at its default threshold, finds the same person on a crop of the image around
        the answer (upscaled to 256 px; squared with the border's own pixels, not zeros: zero
        padding is what lets it see people in a horse): a person it missed in the whole image."""
        h, w = rgb.shape[:2]
        seen = r.visibility > 0.5
        pts = r.image_xy[seen] if seen.sum() >= 4 else r.image_xy
        lo, hi = pts.min(0), pts.max(0)
        size = float(max(hi[0] - lo[0], hi[1] - lo[1], 8.0))
        c = 0.5 * (lo + hi)
        x0, y0 = (int(max(0, c[0] - 0.75 * size)), int(max(0, c[1] - 0.75 * size)))
        x1, y1 = (int(min(w, c[0] + 0.75 * size)), int(min(h, c[1] + 0.75 * size)))
        if x1 - x0 < 8 or y1 - y0 < 8:
            return False
        side = max(x1 - x0, y1 - y0)
        crop = cv2.copyMakeBorder(rgb[y0:y1, x0:x1], 0, side - (y1 - y0), 0, side - (x1 - x0), cv2.BORDER_REPLICATE)
        again = self.mp(np.ascontiguousarray(cv2.resize(crop, (256, 256), interpolation=cv2.INTER_AREA)))
        if again is None:
            return False
        xy = again.image_xy * (side / 256.0) + [x0, y0]
        return bool(np.median(np.linalg.norm(xy - r.image_xy, axis=1)) < 0.15 * size)

    def _retry(self, rgb: np.ndarray, k: np.ndarray):
        for view, factor, threshold in RETRIES:
            padded, pad = pad_image(rgb, factor)
            if view == "mirror":
                padded = np.ascontiguousarray(padded[:, ::-1])
            r = self._detector(threshold)(padded)
            if r is not None:
                r = unview(r, pad, view == "mirror", rgb.shape)
                if (score := self._person(r, rgb, retry=True)) is not None:
                    self.last_view = f"{view} x{factor:g} @{threshold:g}"
                    return (r, *self.adapter.predict(r, k), score)
        return None

    def __call__(self, rgb: np.ndarray, k: np.ndarray) -> Keypoints | None:
        if self.detect and (found := self.detected(rgb, k, 1)):
            return found[0]
        kp = self._find(rgb, k, self.retry, strict=False, search=self.search)
        return self._fallback(rgb, k) if kp is None else self._with_backbone(rgb, k, kp)

    def _find(self, rgb: np.ndarray, k: np.ndarray, retry: bool, strict: bool, search: bool = False
              ) -> Keypoints | None:
        """``__call__`` with its retries and the faceless search on or off; ``strict``: even the first
        answer needs a retry view's evidence (``people`` on windows, which are upscaled views).
        MediaPipe's detector misses many people in grayscale images: those are searched tinted, as
        they are, then tinted at ``GRAY_SMALL`` px (the answer mapped back to the image), and only
        then without a face (as they are, then tinted)."""
        if not is_grayscale(rgb):
            return self._find_in(rgb, k, retry, strict, search)
        warm = tinted(rgb)
        found = self._find_in(warm, k, retry, strict) or self._find_in(rgb, k, retry, strict)
        f = GRAY_SMALL / max(rgb.shape[:2])
        if found is None and f < 1.0:
            small = cv2.resize(warm, (round(rgb.shape[1] * f), round(rgb.shape[0] * f)),
                               interpolation=cv2.INTER_AREA)
            ks = np.array(k, float)
            ks[:2] *= f
            found = self._find_in(small, ks, retry, strict)
            found = None if found is None else scaled(found, 1.0 / f, rgb.shape)
        if found is None and search:  # the faceless search finds more in the gray itself than tinted
            found = self._search(rgb, k) or self._search(warm, k)
        return found

    def _find_in(self, rgb: np.ndarray, k: np.ndarray, retry: bool, strict: bool,
                 search: bool = False) -> Keypoints | None:
        """The detector on the image, then its retries (``retry``), then the faceless search (``search``)."""
        found = self._detect(rgb, k)
        score = None if found is None else self._person(found[0], rgb, retry=strict)
        found = None if score is None else found
        self.last_view = None if found is None else "image"
        if found is None and retry:
            found = self._retry(rgb, k)
            if found is not None:  # a view found the person: no mirror averaging on top
                r, p3, uv, score = found
                return Keypoints(p3, uv, float(np.mean(r.visibility)), r.box(), r.mask, score, self.name)
        if found is None:
            return self._search(rgb, k) if search else None
        r, p3, uv = found
        box = r.box()
        if self.flip:
            w = rgb.shape[1]
            mirrored = self._detect(np.ascontiguousarray(rgb[:, ::-1]), mirrored_camera(k, w))
            if mirrored is not None:
                p3m, uvm = unmirror(mirrored[1], mirrored[2], w)
                size = max(box[2] - box[0], box[3] - box[1], 1.0)
                inside = camera.inside_image(uv, rgb.shape)  # guesses outside the image may disagree
                d = np.linalg.norm(uvm - uv, axis=1)[inside if inside.any() else slice(None)]
                if np.median(d) < 0.25 * size:  # the same person (another one would be far off)
                    p3, uv = 0.5 * (p3 + p3m), 0.5 * (uv + uvm)
        return Keypoints(p3, uv, float(np.mean(r.visibility)), box, r.mask, score, self.name)

    def person_in(self, rgb: np.ndarray, k: np.ndarray, crop: tuple[int, int, int, int], strict: bool = False,
                  painted: np.ndarray | None = None, found: Sequence[Keypoints] = ()) -> Keypoints | None:
        """The person MediaPipe finds on ``crop`` (x0, y0, x1, y1) of ``painted`` (default ``rgb``:
        the frame with the people found so far painted over) who is none of ``found``, in ``rgb``'s
        pixels, blended with the backbone's on ``rgb`` (``backbone_weight``). No retries and no
        faceless search; ``strict``: the answer needs a retry view's evidence (upscaled views)."""
        x0, y0, x1, y1 = crop
        image = rgb if painted is None else painted
        kc = np.array(k, float)
        kc[:2, 2] -= (x0, y0)
        kp = self._find(np.ascontiguousarray(image[y0:y1, x0:x1]), kc, retry=False, strict=strict)
        if kp is None:
            return None
        kp = shifted(kp, x0, y0, image.shape)
        return None if any(same_person(kp, f) for f in found) else self._with_backbone(rgb, k, kp)

    def people(self, rgb: np.ndarray, k: np.ndarray, max_people: int) -> list[Keypoints]:
        """Up to ``max_people`` people: MediaPipe Pose finds one person per call, so each person it
        finds is painted over (``blank_person``) and it is asked again, first on the whole image,
        then, once someone is found, on windows of it (``windows``: its detector sees a whole image
        at 224 px, where the people of a wide group photo are too small), until it finds nobody
        new. Only the first person may come from the retries or the ``fallback``; window answers need
        the guard's retry evidence."""
        if self.detect and (found := self.detected(rgb, k, max_people)):
            return found
        found = []
        work = rgb
        views = [(0, 0, rgb.shape[1], rgb.shape[0])] + windows(*rgb.shape[:2])
        for n_view, (x0, y0, x1, y1) in enumerate(views):
            if n_view > 0 and not found:
                # nobody in the whole image: no windows (where phantoms would get a second chance)
                return [kp] if (kp := self._fallback(rgb, k)) is not None else []
            while len(found) < max_people:
                kw = np.array(k, float)
                kw[:2, 2] -= (x0, y0)
                # the retries rescue a missed lone person (on painted images they invent); a window
                # is an upscaled view: its answers need a retry's evidence
                kp = self._find(np.ascontiguousarray(work[y0:y1, x0:x1]), kw, retry=self.retry and not found,
                                search=self.search and not found and n_view == 0,
                                strict=n_view > 0)
                if kp is None:
                    break
                kp = shifted(kp, x0, y0, work.shape)
                if any(same_person(kp, f) for f in found):
                    break
                found.append(kp)
                work = blank_person(work, kp)
        while self.search and found and len(found) < max_people:  # people the detector missed
            kp = self._search(work, k)
            if kp is None or any(same_person(kp, f) for f in found):
                break
            found.append(kp)
            work = blank_person(work, kp)
        return [self._with_backbone(rgb, k, kp) for kp in found]


class BackboneSource:
    """The volumetric stacked hourglass (recon.backbone) without any other detector: its crop
    search (``recon.backbone.search.CropSearch``) locates the person and predicts J+. ``None``
    when the mean peak confidence is under ``min_confidence`` (the network saw no person-free
    image in training, so this is a weak test). No person mask."""

    name = "backbone"

    def __init__(self, body: BodyModel | None = None, weights=None, passes: int = 3, min_confidence: float = 0.05,
                 device: str = "cpu", jit: bool = True, quick_locate: bool = True, flip: bool = False):
        self.search = CropSearch.load(body, weights, device, jit, passes=passes, quick_locate=quick_locate, flip=flip)
        self.min_confidence = min_confidence

    @property
    def flip(self) -> bool:
        return self.search.flip

    def __call__(self, rgb: np.ndarray, k: np.ndarray) -> Keypoints | None:
        pts, uv, conf, _ = self.search.locate(rgb, k)
        c = float(conf.mean())
        if c < self.min_confidence:
            return None
        h, w = rgb.shape[:2]
        x0, y0 = np.clip(uv.min(0), 0, [w, h])
        x1, y1 = np.clip(uv.max(0), 0, [w, h])
        return Keypoints(pts - pts[:1], uv, c, (float(x0), float(y0), float(x1), float(y1)), found_by=self.name)

    def on_crop(self, rgb: np.ndarray, k: np.ndarray, kp: Keypoints, passes: int = 2) -> Keypoints:
        """The network on the metric crop of another source's keypoints ``kp`` (then ``passes`` - 1
        more passes, each on the crop of the previous): its J+ where ``kp`` says the person is,
        with its mean peak confidence; ``kp``'s box and mask."""
        search = self.search
        crop = crop_from_keypoints(kp.points2d, k, search.template, 1.0, kp.points3d)
        for p in range(passes):
            pts, uv, conf = search.net.predict([rgb], [crop])
            if p < passes - 1:
                crop = crop_from_keypoints(uv[0], k, search.template, search.net.depth_scale[-1],
                                           search.depth_points(pts[0]))
        return Keypoints(pts[0] - pts[0][:1], uv[0], float(conf[0].mean()), kp.box, kp.mask, found_by=self.name)
