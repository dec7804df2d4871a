"""How the camera turned between frames, from the background: corners tracked by pyramidal
Lucas-Kanade optical flow outside the people's boxes (their motion is not the camera's), and the
rotation that best explains them. For a camera that only turns (a pan, a tilt, a hand-held
camera's shake about its centre) the background's directions turn by the camera's rotation
whatever their depth, so each step is the rotation of the tracked points' rays (two-point RANSAC,
then a least-squares fit to the inliers: three parameters, well posed on a strip of background
where a homography's eight are not); a camera that also moves gives the rotation of its distant
background.

Each step carries its own confidence. It is *measured* only where it rests on ``min_points``
inliers that are most of the points tracked (``min_inlier_share``), spread over the frame (not one
corner or one column: ``min_spread``), and is a turn a real camera makes: under
``max_degrees_per_second``, and not a spike away from the measured steps around it (a camera has
inertia: its rate of turn changes smoothly). Any other step is *unknown*: its rate is interpolated
from the measured steps on both sides when they are within ``max_gap_seconds``, else it is taken as
still. A clip measured on less than ``MIN_MEASURED`` of its steps is taken as still
(``TurnEstimate.known``).

``CameraRotations(k)(frames)`` ((image, people's boxes) pairs) -> ``TurnEstimate``: (T, 3, 3)
rotations of each frame's camera relative to the first one's (OpenCV camera axes: ``x_t = R_t x_0``
for a direction), the points each step rested on and whether it was measured; or frame by frame,
``add(image, boxes)`` (``hold()`` for a frame that could not be read) then ``result()``.
``recon video`` takes the turn out of the people's motion when it is known and the camera turned
more than ``MOVING_DEGREES``.

A camera that moves (travels) is detected, not measured: where it moved, background points at
different depths shift against each other (parallax), so a turn leaves many of them out while a
turn and a move together (an essential matrix) explain them; ``TurnEstimate.travelled`` says so
when the typical match shows that on ``TRAVEL_SHARE`` of its points (points of real texture only:
corners found in the noise of a blank wall drift along it and look like a move), growing by
``TRAVEL_RATE`` a second. The matches' points are kept (``TurnEstimate.matches``) for
``recon.video.camera_travel``, which then fits the turn and the move together.
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

MOVING_DEGREES = 2.0  # a camera that turned more than this over a clip is not static
MIN_MEASURED = 0.5  # a clip whose turn is measured on fewer of its steps is taken as still
TRAVEL_SHARE = 0.1  # a camera moved where a typical match has this share of its points showing parallax
PARALLAX_SPREAD = 0.3  # ... and spread across this share of the frame's width
TRAVEL_RATE = 0.02  # ... growing this much a second (radians: its speed over the near background's distance)
MIN_TEXTURE = 5e-4  # points whose corner strength (``corner_strength``) is under this show no parallax


@dataclass
class TurnEstimate:
    """``rotations`` (T, 3, 3): each frame's camera relative to the first one's; ``points`` (T,):
    the inliers each step (frame t-1 -> t) rested on, 0 where none; ``measured`` (T,): the step was
    measured with confidence (False for the first frame, and where it was filled in)."""

    rotations: np.ndarray
    points: np.ndarray
    measured: np.ndarray
    parallax: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (M,) per match: ``parallax``'s share
    rates: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (M,) its parallax a second (radians)
    # the background points of each measured match: (frame a, frame b, a's (N, 2), b's (N, 2)), the frames' pixels
    matches: list = field(default_factory=list)

    @property
    def travelled(self) -> bool:
        """The camera moved, not only turned: the median match shows parallax on ``TRAVEL_SHARE`` of
        its points (a background with depth is needed to see it: a far one shows none), growing
        by ``TRAVEL_RATE`` a second (a hand-held camera's sway of a few centimetres shows parallax
        on a near ground too, but little and slowly)."""
        if not len(self.parallax) or float(np.median(self.parallax)) <= TRAVEL_SHARE:
            return False
        return float(np.median(self.rates[self.parallax > 0])) > TRAVEL_RATE

    @property
    def measured_share(self) -> float:
        """The share of the clip's steps that were measured (1 for a single frame)."""
        steps = len(self.measured) - 1
        return 1.0 if steps <= 0 else float(self.measured[1:].sum()) / steps

    @property
    def known(self) -> bool:
        """Enough of the clip measured for its turn to be trusted (``MIN_MEASURED``)."""
        return self.measured_share >= MIN_MEASURED

    @property
    def degrees(self) -> float:
        """The largest angle between the first frame's camera and any later one's."""
        return turned_degrees(self.rotations)

    @property
    def turned(self) -> bool:
        """The turn is known and larger than ``MOVING_DEGREES``: worth taking out of the motion."""
        return self.known and self.degrees > MOVING_DEGREES


@dataclass
class _Key:
    """A frame the next ones are measured against: its image and background corners, the last
    frame linked to it and that frame's rotation from it, the inliers of its first match."""

    index: int
    gray: np.ndarray
    corners: np.ndarray | None
    last: int
    last_rotation: np.ndarray
    first_inliers: int = 0


@dataclass
class CameraRotations:
    """The turn of the camera frame to frame (module doc). Each frame is matched to a key frame, not
    to the frame before, so that a still camera's measurement noise does not add up frame after
    frame; a new key is taken where the key's points thin out (the camera turned away, people
    covered them) or it is lost. ``fps``: the frames' rate (the limits on a step are per second);
    ``corners``: points looked for on a key frame."""

    k: np.ndarray
    fps: float = 30.0
    corners: int = 200
    min_points: int = 20
    min_inlier_share: float = 0.5
    min_spread: float = 0.03  # the inliers' 10-90 % range, as a share of the frame's width and of its height
    ransac_px: float = 1.0
    max_degrees_per_second: float = 180.0  # a whip pan's; faster steps are failures of the match
    spike_degrees_per_second: float = 30.0  # a step this far from its neighbours' median rate is a spike
    neighbours: int = 5  # steps each side that a step is compared with
    max_gap_seconds: float = 1.0  # unknown steps between measured ones this close are interpolated
    rekey_share: float = 0.5  # a new key where fewer of the key's first inliers are left
    rekey_degrees: float = 10.0  # ... or the camera turned this far from it
    lost_after: int = 5  # frames: a key not matched this long is replaced
    max_side: int = 320  # frames are looked at this small (the turn is a few parameters: cheap and enough)

    def __post_init__(self):
        self._steps: list[tuple[np.ndarray | None, int]] = []  # step t -> t+1: (rotation vector, inliers)
        self._frames, self._key, self._prev, self._k = 0, None, None, None
        self._moves: list[tuple[float, float]] = []  # per match: ``parallax``'s share, the parallax a second
        self._move: tuple[float, float] | None = None
        self._matches: list[tuple[int, int, np.ndarray, np.ndarray]] = []
        self._points: tuple[np.ndarray, np.ndarray] | None = None  # the last match's background points

    def __call__(self, frames: Iterable[tuple[np.ndarray, np.ndarray | None]]) -> TurnEstimate:
        """``frames``: (RGB (H, W, 3) uint8, the people's (n, 4) x0, y0, x1, y1 boxes or None),
        streamed."""
        self.__post_init__()
        for rgb, boxes in frames:
            self.add(rgb, boxes)
        return self.result()

    def add(self, rgb: np.ndarray, boxes: np.ndarray | None) -> None:
        """The next frame, as it comes (``recon video`` feeds the frames of its per-frame pass)."""
        f = min(1.0, self.max_side / max(rgb.shape[:2]))
        if self._k is None:
            self._k = np.diag([f, f, 1.0]) @ np.asarray(self.k, float)
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        if f < 1.0:
            size = (round(rgb.shape[1] * f), round(rgb.shape[0] * f))
            gray = cv2.resize(gray, size, interpolation=cv2.INTER_AREA)
        mask = background_mask(gray.shape, None if boxes is None else np.asarray(boxes, float) * f)
        t = self._frames
        self._frames += 1
        if t:
            self._steps.append((None, 0))
        key, prev = self._key, self._prev
        self._prev = (t, gray, mask)
        if key is None:
            self._key = self._new_key(t, gray, mask)
            return
        rot, used = self._match(key.gray, key.corners, gray, mask, key.last_rotation)
        self._keep_move(key.index)
        if rot is not None:  # the steps since the key's last linked frame share the turn between them
            step = Rotation.from_matrix(rot @ key.last_rotation.T).as_rotvec() / (t - key.last)
            self._steps[key.last:t] = [(step, used)] * (t - key.last)
            self._keep_match(key.index, t)
            key.last, key.last_rotation = t, rot
            key.first_inliers = key.first_inliers or used
            if used < self.rekey_share * key.first_inliers or \
                    np.degrees(Rotation.from_matrix(rot).magnitude()) > self.rekey_degrees:
                self._key = self._new_key(t, gray, mask)
            return
        if prev is not None and prev[0] == t - 1 and prev[0] != key.index:  # the frame before, then
            corners = _corners(prev[1], prev[2], self.corners)
            rot, used = self._match(prev[1], corners, gray, mask)
            self._keep_move(t - 1)
            if rot is not None:
                self._steps[t - 1] = (Rotation.from_matrix(rot).as_rotvec(), used)
                self._keep_match(t - 1, t)
                self._key = self._new_key(t, gray, mask)
                return
        if t - key.last >= self.lost_after:
            self._key = self._new_key(t, gray, mask)

    def hold(self) -> None:
        """A frame that could not be read: its steps are measured across it, from the key."""
        if self._frames:
            self._steps.append((None, 0))
        self._frames += 1

    def result(self) -> TurnEstimate:
        """The frames added so far (``__call__``)."""
        n = len(self._steps)
        rates = np.zeros((n, 3))
        ok = np.array([s[0] is not None for s in self._steps], bool)
        for i in np.flatnonzero(ok):
            rates[i] = self._steps[i][0]
        ok &= np.degrees(np.linalg.norm(rates, axis=1)) <= self.max_degrees_per_second / self.fps
        ok = ok & ~self._spikes(rates, ok)
        filled = fill_unknown(rates, ok, max(1, round(self.max_gap_seconds * self.fps)))
        rotations = [np.eye(3)]
        for r in Rotation.from_rotvec(filled).as_matrix() if n else []:
            rotations.append(r @ rotations[-1])
        points = np.array([0] + [s[1] for s in self._steps], int)
        rotations = np.stack(rotations)
        moves = np.array(self._moves, float).reshape(-1, 2)
        return TurnEstimate(rotations, points, np.concatenate([[False], ok]), moves[:, 0], moves[:, 1],
                            list(self._matches))

    def _keep_match(self, a: int, b: int) -> None:
        scale = self.k[0, 0] / self._k[0, 0]  # back to the frames' own pixels
        p0, p1 = self._points
        self._matches.append((a, b, p0 * scale, p1 * scale))

    def _keep_move(self, first: int) -> None:
        if self._move is not None:  # the parallax per second: how fast the camera moved against the near background
            share, angle = self._move
            self._moves.append((share, angle * self.fps / max(self._frames - 1 - first, 1)))
        self._move = None

    def _new_key(self, t: int, gray: np.ndarray, mask: np.ndarray) -> _Key:
        return _Key(t, gray, _corners(gray, mask, self.corners), t, np.eye(3))

    def _spikes(self, rates: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """(S,) measured steps that no real camera makes: away from the median rate of the measured
        steps around them, or, with fewer than two of those to compare with, not small."""
        limit = np.radians(self.spike_degrees_per_second / self.fps)
        spike = np.zeros(len(rates), bool)
        for i in np.flatnonzero(ok):
            near = np.flatnonzero(ok[max(0, i - self.neighbours):i + self.neighbours + 1]) + max(0, i - self.neighbours)
            near = near[near != i]
            centre = np.median(rates[near], 0) if len(near) >= 2 else np.zeros(3)
            spike[i] = np.linalg.norm(rates[i] - centre) > limit
        return spike

    def _match(self, a: np.ndarray, corners: np.ndarray | None, b: np.ndarray, mask_b: np.ndarray,
               guess: np.ndarray | None = None) -> tuple[np.ndarray | None, int]:
        """The rotation from frame ``a``'s camera to ``b``'s, from ``a``'s background ``corners``,
        and the inliers it rests on; None where it is not measured with confidence (module doc).
        ``guess``: a rotation near the answer, where the flow starts (the key's last match)."""
        if corners is None or len(corners) < self.min_points:
            return None, 0
        start = corners.copy() if guess is None else _turn(corners, guess, self._k)
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
        nxt, status, _ = cv2.calcOpticalFlowPyrLK(a, b, corners, start, winSize=(21, 21), maxLevel=3, flags=flags)
        back, status_back, _ = cv2.calcOpticalFlowPyrLK(b, a, nxt, corners.copy(), winSize=(21, 21), maxLevel=3,
                                                        flags=flags)
        ok = (status[:, 0] == 1) & (status_back[:, 0] == 1) & (np.linalg.norm(back - corners, axis=-1)[:, 0] < 0.5)
        p0, p1 = corners[ok, 0].astype(float), nxt[ok, 0].astype(float)
        h, w = b.shape
        inside = (p1[:, 0] >= 0) & (p1[:, 0] <= w - 1) & (p1[:, 1] >= 0) & (p1[:, 1] <= h - 1)
        p0, p1 = p0[inside], p1[inside]
        keep = mask_b[p1[:, 1].round().astype(int), p1[:, 0].round().astype(int)]  # not behind a person now
        p0, p1 = p0[keep], p1[keep]
        if len(p0) < self.min_points:
            return None, 0
        rot, inliers = ransac_rotation(p0, p1, self._k, self.ransac_px)
        used = int(inliers.sum())
        textured = corner_strength(a, p0) >= MIN_TEXTURE  # noise on a blank wall drifts: no evidence of a move
        self._move = parallax(p0[textured], p1[textured], self._k, rot, self.ransac_px, (h, w))
        self._points = (p0[textured], p1[textured])
        if used < self.min_points or used < self.min_inlier_share * len(p0) or \
                min(spread(p1[inliers], (h, w))) < self.min_spread:
            return None, used
        return rot, used


def ransac_rotation(p0: np.ndarray, p1: np.ndarray, k: np.ndarray, px: float, hypotheses: int = 64,
                    seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The rotation R that best takes the rays of pixels ``p0`` (N, 2) to those of ``p1``
    (``x1 ~ K R K^-1 x0``): two-point hypotheses (deterministic draws), the one with the most
    reprojections within ``px`` refitted to its inliers twice. Returns (3, 3) and (N,) inliers."""
    k_inv = np.linalg.inv(k)
    r0 = _rays(p0, k_inv)
    r1 = _rays(p1, k_inv)
    pairs = np.random.default_rng(seed).integers(0, len(p0), (hypotheses, 2))
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    candidates = kabsch(r0[pairs], r1[pairs])
    inliers = _within(candidates, r0, p1, k, px)
    best = inliers[np.argmax(inliers.sum(1))]
    rot = np.eye(3)
    for _ in range(2):
        if best.sum() < 2:
            break
        rot = kabsch(r0[best][None], r1[best][None])[0]
        best = _within(rot[None], r0, p1, k, px)[0]
    return rot, best


def parallax(p0: np.ndarray, p1: np.ndarray, k: np.ndarray, rot: np.ndarray, px: float, shape: tuple[int, int],
             min_spread: float = PARALLAX_SPREAD) -> tuple[float, float]:
    """How much of a match shows that the camera moved: the share of the points (N, 2) that the
    camera's turn ``rot`` misses (by more than ``px``) but a turn and a move together explain (an
    essential matrix, RANSAC within ``px``): points nearer than the rest seen from a camera that
    moved; and how far the turn misses those points (their median, radians). Near 0 for a camera
    that only turns. Points that span less than ``min_spread`` of the frame's (H, W) ``shape``
    across count as none: one thing moving (a person's edge the boxes left out), not the scene
    seen from elsewhere."""
    if len(p0) < 8:
        return 0.0, 0.0
    x = _rays(p0, np.linalg.inv(k)) @ (k @ rot).T
    off = np.linalg.norm(x[:, :2] / x[:, 2:] - p1, axis=1)
    missed = off > px
    if missed.sum() == 0:
        return 0.0, 0.0
    try:
        e, mask = cv2.findEssentialMat(p0, p1, k, method=cv2.RANSAC, prob=0.999, threshold=px)
    except cv2.error:  # degenerate (the points hardly moved): nothing a move explains
        return 0.0, 0.0
    if e is None or mask is None or e.shape != (3, 3):
        return 0.0, 0.0
    moved = (mask[:, 0] > 0) & missed
    if spread(p1[moved], shape)[0] < min_spread:
        return 0.0, 0.0
    return float(moved.sum()) / len(p0), float(np.median(off[moved])) / float(k[0, 0])


def corner_strength(gray: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N,) the smaller eigenvalue of the image's structure tensor (OpenCV's, 5 x 5 blocks) at
    ``points`` (N, 2): how well a point's place is pinned down by the texture around it."""
    eig = cv2.cornerMinEigenVal(gray, 5, 3)
    h, w = gray.shape
    return eig[points[:, 1].round().astype(int).clip(0, h - 1), points[:, 0].round().astype(int).clip(0, w - 1)]


def kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(M, 3, 3): for each of M sets of unit vectors (M, N, 3) the rotation that best takes ``a`` to ``b``."""
    u, _, vt = np.linalg.svd(np.einsum("mni,mnj->mij", b, a))
    d = np.sign(np.linalg.det(u @ vt))
    return u @ (np.eye(3) * np.stack([np.ones_like(d), np.ones_like(d), d], -1)[:, None]) @ vt


def spread(points: np.ndarray, shape: tuple[int, int]) -> tuple[float, float]:
    """How far ``points`` (N, 2) x, y reach across a frame of ``shape`` (H, W): their 10-90 %
    range in x as a share of the width, in y of the height."""
    if len(points) < 2:
        return 0.0, 0.0
    lo, hi = np.percentile(points, [10, 90], axis=0)
    return float((hi[0] - lo[0]) / shape[1]), float((hi[1] - lo[1]) / shape[0])


def fill_unknown(rates: np.ndarray, ok: np.ndarray, max_gap: int) -> np.ndarray:
    """(S, 3) the rates with the unknown steps interpolated between the measured steps on both sides
    when those are at most ``max_gap`` steps apart, else zero (still)."""
    out = np.where(ok[:, None], rates, 0.0)
    known = np.flatnonzero(ok)
    for i in np.flatnonzero(~ok):
        after = np.searchsorted(known, i)
        if 0 < after < len(known) and known[after] - known[after - 1] <= max_gap:
            lo, hi = known[after - 1], known[after]
            out[i] = rates[lo] + (rates[hi] - rates[lo]) * (i - lo) / (hi - lo)
    return out


def background_mask(shape: tuple[int, int], boxes: np.ndarray | None, grow: float = 0.1) -> np.ndarray:
    """(H, W) bool: True away from the people's boxes (each grown by ``grow`` of its size)."""
    mask = np.ones(shape, bool)
    for x0, y0, x1, y1 in (np.asarray(boxes, float).reshape(-1, 4) if boxes is not None else []):
        g = grow * max(x1 - x0, y1 - y0)
        mask[max(0, int(y0 - g)):max(0, int(y1 + g + 1)), max(0, int(x0 - g)):max(0, int(x1 + g + 1))] = False
    return mask


def turned_degrees(rotations: np.ndarray) -> float:
    """The largest angle (degrees) between the first frame's camera and any later one's."""
    cos = (np.trace(rotations, axis1=1, axis2=2) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max())


def _corners(gray: np.ndarray, mask: np.ndarray, n: int) -> np.ndarray | None:
    """Up to ``n`` (N, 1, 2) float32 corners of ``gray`` where ``mask`` is True."""
    return cv2.goodFeaturesToTrack(gray, n, 0.01, 5, mask=mask.astype(np.uint8))


def _turn(points: np.ndarray, rot: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(N, 1, 2) float32: where pixels ``points`` go when the camera turns by ``rot``."""
    x = _rays(points[:, 0].astype(float), np.linalg.inv(k)) @ (k @ rot).T
    return (x[:, :2] / x[:, 2:]).reshape(-1, 1, 2).astype(np.float32)  # its own memory: OpenCV writes into it


def _rays(p: np.ndarray, k_inv: np.ndarray) -> np.ndarray:
    r = np.concatenate([p, np.ones((len(p), 1))], 1) @ k_inv.T
    return r / np.linalg.norm(r, axis=1, keepdims=True)


def _within(rots: np.ndarray, r0: np.ndarray, p1: np.ndarray, k: np.ndarray, px: float) -> np.ndarray:
    """(M, N): the rays ``r0`` turned by each of ``rots`` land within ``px`` of ``p1``."""
    x = r0 @ (k @ rots).transpose(0, 2, 1)
    z = x[..., 2]
    uv = x[..., :2] / np.where(np.abs(z) > 1e-9, z, 1e-9)[..., None]
    return (z > 0) & (np.linalg.norm(uv - p1, axis=-1) < px)
