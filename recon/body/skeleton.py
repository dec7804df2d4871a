"""The canonical skeleton: 24 body joints, 18 surface landmarks and the frame they live in.

Conventions (documented here once, tested in tests/test_conventions.py):

* Units are metres.
* Body frame: +Y up, +Z forward (the direction the subject faces in the rest pose),
  +X towards the subject's LEFT. Right-handed. This is the SMPL / glTF convention.
* Posed outputs are expressed with the pelvis joint at ``transl`` (the origin by default).
* Pose = one rotation per joint, relative to its parent, in world-aligned rest axes
  (SMPL convention): the global rotation of joint j is ``G_j = G_parent(j) @ R_j`` and the
  identity pose is the body model's rest pose (an A-pose for anny, a T-pose for SMPL files).
* "left"/"right" are the subject's own sides.

Joint order is SMPL's (index: name); ``JOINT_PARENTS`` is its kinematic tree.
Landmarks are fixed mesh vertices picked by geometric rules (recon.body.landmarks) on the
rest mesh; each has a parent joint, giving the 42-point tree ``KINTREE_PLUS`` of SMPLR
(thesis eq. 2.1-2.3: N_i and B_i are taken along these parent links).
"""
from __future__ import annotations

JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee",
    "spine2", "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot",
    "neck", "left_collar", "right_collar", "head", "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hand", "right_hand",
)
JOINT_PARENTS: tuple[int, ...] = (
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21,
)
NUM_JOINTS = len(JOINT_NAMES)

# 18 surface landmarks (SMPLR ch. 2, Fig. 2.3: joints are complemented by surface points
# that fix body girth and the twist of head, limbs and feet). Name -> parent joint.
LANDMARKS: tuple[tuple[str, str], ...] = (
    ("head_top", "head"),
    ("nose", "head"),
    ("chest", "spine3"),
    ("upper_back", "spine3"),
    ("belly", "spine1"),
    ("sacrum", "pelvis"),
    ("left_shoulder_top", "left_shoulder"),
    ("right_shoulder_top", "right_shoulder"),
    ("left_elbow_back", "left_elbow"),
    ("right_elbow_back", "right_elbow"),
    ("left_hand_outer", "left_wrist"),
    ("right_hand_outer", "right_wrist"),
    ("left_hip_side", "left_hip"),
    ("right_hip_side", "right_hip"),
    ("left_knee_front", "left_knee"),
    ("right_knee_front", "right_knee"),
    ("left_toe_tip", "left_foot"),
    ("right_toe_tip", "right_foot"),
)
LANDMARK_NAMES: tuple[str, ...] = tuple(n for n, _ in LANDMARKS)

# J+ = joints followed by landmarks (42 points) and its kinematic tree kappa.
POINT_NAMES: tuple[str, ...] = JOINT_NAMES + LANDMARK_NAMES
KINTREE_PLUS: tuple[int, ...] = JOINT_PARENTS + tuple(JOINT_NAMES.index(p) for _, p in LANDMARKS)
NUM_POINTS = len(POINT_NAMES)


def _mirror_name(name: str) -> str:
    if name.startswith("left_"):
        return "right_" + name[5:]
    if name.startswith("right_"):
        return "left_" + name[6:]
    return name


# Index maps for a left/right flip: point i of the flipped body is point MIRROR[i] of the original.
JOINT_MIRROR: tuple[int, ...] = tuple(JOINT_NAMES.index(_mirror_name(n)) for n in JOINT_NAMES)
POINT_MIRROR: tuple[int, ...] = tuple(POINT_NAMES.index(_mirror_name(n)) for n in POINT_NAMES)

# Groups used by the per-joint error table (thesis Table 2.1).
JOINT_GROUPS: dict[str, tuple[str, ...]] = {
    "head": ("neck", "head"),
    "torso": ("pelvis", "spine1", "spine2", "spine3", "left_collar", "right_collar"),
    "shoulder": ("left_shoulder", "right_shoulder"),
    "elbow": ("left_elbow", "right_elbow"),
    "wrist": ("left_wrist", "right_wrist", "left_hand", "right_hand"),
    "hip": ("left_hip", "right_hip"),
    "knee": ("left_knee", "right_knee"),
    "foot": ("left_ankle", "right_ankle", "left_foot", "right_foot"),
}


def joint_index(name: str) -> int:
    """Index of a canonical joint or landmark in J+ (joints first), with a clear error."""
    try:
        return POINT_NAMES.index(name)
    except ValueError:
        raise KeyError(
            f"unknown joint or landmark {name!r}; known names: {', '.join(POINT_NAMES)}"
        ) from None
