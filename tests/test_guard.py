"""The person guard: MediaPipe's phantoms on person-free images are refused, people are kept."""
import numpy as np
import pytest
import skimage.data

from recon import camera, io
from recon.body import default_body
from recon.demo import EXAMPLES
from recon.keypoints import available as mediapipe_available
from recon.keypoints.adapter import WEIGHTS as ADAPTER_WEIGHTS
from recon.keypoints.base import Keypoints
from recon.keypoints.sources import TRUSTED_CONFIDENCE, MediaPipeSource
from recon.people import guard
from recon.people.mediapipe import MODELS, MPPose
from recon.reconstruction import ReconstructorConfig
from recon.synth.dataset import BENCHMARKS
from recon.synth.scene import SceneSampler

needs_mediapipe = pytest.mark.skipif(not (mediapipe_available() and ADAPTER_WEIGHTS.exists()),
                                     reason="needs mediapipe (scripts/setup.sh) and the adapter weights")


def _standing(scale=100.0, seen=1.0):
    """MediaPipe-like landmarks of an upright person (image y down, world y down, metres)."""
    world = np.zeros((33, 3))
    pts = {0: (0, -0.65), 11: (0.18, -0.45), 12: (-0.18, -0.45), 13: (0.22, -0.2), 14: (-0.22, -0.2),
           15: (0.24, 0.05), 16: (-0.24, 0.05), 23: (0.1, 0.0), 24: (-0.1, 0.0), 25: (0.1, 0.42),
           26: (-0.1, 0.42), 27: (0.1, 0.85), 28: (-0.1, 0.85)}
    for k, (x, y) in pts.items():
        world[k, :2] = (x, y)
    for k in range(33):
        if k not in pts:
            world[k, :2] = world[0, :2] + 0.01 * k
    xy = world[:, :2] * scale + [160.0, 160.0]
    mask = np.zeros((320, 320), bool)
    mask[90:250, 135:185] = True
    return MPPose(xy, np.full(33, seen), world, mask)


def test_evidence_and_score_follow_the_answer():
    person = guard.evidence(_standing(), (320, 320))
    assert person["asym"] < 1e-6 and person["proj"] < 0.05 and 0.2 < person["aspect"] < 0.6
    doubtful = guard.evidence(_standing(seen=0.2), (320, 320))  # MediaPipe unsure of every landmark
    tiny = guard.evidence(_standing(scale=8.0), (320, 320))  # a few pixels tall
    no_mask = guard.evidence(MPPose(*[getattr(_standing(), f) for f in ("image_xy", "visibility", "world")], None),
                             (320, 320))
    assert no_mask["mask_box"] == -1.0
    for model in MODELS:
        g = guard.for_model(model)
        assert g.accept(person) and g.accept(person, retry=True)
        assert g.score(doubtful) < g.score(person) - 3 and not g.accept(doubtful)
        assert g.score(tiny) < g.score(person)
        assert g.accept(no_mask)  # no mask: neutral, not a refusal


def test_a_retry_answer_needs_more_than_a_first_answer():
    for model in MODELS:
        t = guard.for_model(model).threshold
        assert t["retry"] > t["image"] and t["confirmed"] <= t["retry"]
    assert guard.for_model("lite") is guard.FULL  # no guard of its own


@needs_mediapipe
@pytest.mark.parametrize("name", ["horse", "logo", "coffee", "rocket", "checkerboard"])
def test_no_body_on_person_free_images(name):
    img = np.asarray(getattr(skimage.data, name)())
    img = np.ascontiguousarray(np.repeat(img[..., None], 3, 2) if img.ndim == 2 else img[..., :3]).astype(np.uint8)
    k = camera.default_intrinsics(*img.shape[:2])
    src = MediaPipeSource(fallback=True, search=True)  # nor do the backbone or the faceless search find one
    assert src(img, k) is None
    assert src.people(img, k, 4) == []  # nor when asked for several people


@needs_mediapipe
def test_the_guard_is_what_refuses_the_horse():
    """Without the guard MediaPipe's retries find a body on the horse (the phantom this guards), with
    the full landmark model, whose answers the guard was fitted on."""
    img = np.ascontiguousarray(skimage.data.horse().astype(np.uint8)[..., None].repeat(3, 2) * 255)
    k = camera.default_intrinsics(*img.shape[:2])
    assert MediaPipeSource(guard=False, model="full")(img, k) is not None
    assert MediaPipeSource(guard=True, model="full")(img, k) is None


@needs_mediapipe
@pytest.mark.parametrize("path", sorted(EXAMPLES.glob("*.jpg")), ids=lambda p: p.name)
def test_people_in_the_bundled_photos_are_kept(path):
    img = io.load_image(path)
    src = MediaPipeSource(fallback=True, backbone_weight=ReconstructorConfig.backbone_weight)  # recon run's
    kp = src(img, camera.default_intrinsics(*img.shape[:2]))
    assert kp is not None and kp.person_score >= src.person_guard.threshold["image"]
    assert kp.found_by == "mediapipe"  # the backbone, which learnt our renders, is not trusted on photos


@pytest.fixture(scope="module")
def occluded_person() -> dict:
    """synth-val image 27, rendered: a person behind an occluder, whom MediaPipe's answers miss."""
    return SceneSampler(default_body(), BENCHMARKS["synth-val"]["split"], BENCHMARKS["synth-val"]["seed"]).sample(27)


@needs_mediapipe
def test_the_backbone_stands_in_only_where_mediapipe_finds_nobody(monkeypatch, occluded_person):
    """synth-val image 27 (a person behind an occluder): with MediaPipe finding nobody, the fallback's
    backbone answers, says so, and puts the joints where the person is; without it, nobody."""
    s = occluded_person
    rgb, k = s["rgb"], s["K"].astype(np.float64)
    src = MediaPipeSource(fallback=True)
    monkeypatch.setattr(src, "_find", lambda *args, **kwargs: None)  # MediaPipe finds nobody, whatever the CPU
    kp = src(rgb, k)
    assert kp is not None and kp.found_by == "backbone" and kp.mask is None and src.last_view == "backbone"
    assert kp.confidence >= TRUSTED_CONFIDENCE
    height = np.ptp(s["points2d"][:24, 1])
    assert np.median(np.linalg.norm(kp.points2d - s["points2d"], axis=1)) < 0.1 * height
    assert [p.found_by for p in src.people(rgb, k, 3)] == ["backbone"]  # one person, not one per window
    src.fallback = False
    assert src(rgb, k) is None and src.people(rgb, k, 3) == []


@needs_mediapipe
def test_the_backbone_blends_into_mediapipe_people_where_it_is_confident(monkeypatch, occluded_person):
    """The same rendered person, with MediaPipe's answer standing in as the true J+ shifted 6 px:
    the backbone on its crop finds the person, and the J+ become the weighted mean; at weight 0 they
    stay MediaPipe's."""
    s = occluded_person
    rgb, k = s["rgb"], s["K"].astype(np.float64)
    p3 = s["points3d"].astype(np.float64)
    given = Keypoints(p3 - p3[:1], s["points2d"].astype(np.float64) + 6.0, 0.9, (0.0, 0.0, 256.0, 256.0),
                      found_by="mediapipe")
    src = MediaPipeSource(backbone_weight=0.75)
    monkeypatch.setattr(src, "_find", lambda *args, **kwargs: given)
    b = src.backbone.on_crop(rgb, k, given)
    height = np.ptp(s["points2d"][:24, 1])
    assert b.confidence >= TRUSTED_CONFIDENCE
    assert np.median(np.linalg.norm(b.points2d - s["points2d"], axis=1)) < 0.1 * height
    kp = src(rgb, k)
    assert kp.found_by == "mediapipe+backbone"
    np.testing.assert_allclose(kp.points2d, 0.25 * given.points2d + 0.75 * b.points2d, atol=1e-6)
    np.testing.assert_allclose(kp.points3d, 0.25 * given.points3d + 0.75 * b.points3d, atol=1e-9)
    src.backbone_weight = 0.0
    assert src(rgb, k) is given
