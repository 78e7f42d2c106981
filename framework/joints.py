"""The canonical joint vocabulary and the maps from common source namings to it.

Features are defined on canonical joints so that they hold across skeletons. A source
skeleton maps each canonical name it has to one of its joints (``Skeleton.canonical``).

Joint *positions* are the points where a segment starts: ``lknee`` is the knee centre,
``lwrist`` the wrist centre, ``ltoes`` the ball of the foot, ``headtop`` the top of the
head (an ASF/BVH end site).
"""
from __future__ import annotations

#: Canonical joints, in a fixed order used by every canonical position array.
CANONICAL_JOINTS: tuple[str, ...] = (
    "root",
    "lhip", "lknee", "lankle", "ltoes",
    "rhip", "rknee", "rankle", "rtoes",
    "lowerback", "upperback", "chest", "neck", "head", "headtop",
    "lclavicle", "lshoulder", "lelbow", "lwrist", "lfingers",
    "rclavicle", "rshoulder", "relbow", "rwrist", "rfingers",
)

#: Canonical joints every ingested skeleton must provide (features rely on them).
REQUIRED_JOINTS: tuple[str, ...] = (
    "root", "lhip", "lknee", "lankle", "rhip", "rknee", "rankle",
    "head", "lshoulder", "lelbow", "lwrist", "rshoulder", "relbow", "rwrist",
)

# Acclaim ASF skeletons (CMU and HDM05 share bone names). A skeleton joint sits at the
# *start* of the ASF bone of the same name (see plugins/formats/asf_amc.py), so the knee
# is the start of the tibia and the wrist the start of the "wrist" bone.
_ASF = {
    "root": "root",
    "lhip": "lfemur", "lknee": "ltibia", "lankle": "lfoot", "ltoes": "ltoes",
    "rhip": "rfemur", "rknee": "rtibia", "rankle": "rfoot", "rtoes": "rtoes",
    "lowerback": "lowerback", "upperback": "upperback", "chest": "thorax",
    "neck": "lowerneck", "head": "head", "headtop": "head_end",
    "lclavicle": "lclavicle", "lshoulder": "lhumerus", "lelbow": "lradius",
    "lwrist": "lwrist", "lfingers": "lfingers",
    "rclavicle": "rclavicle", "rshoulder": "rhumerus", "relbow": "rradius",
    "rwrist": "rwrist", "rfingers": "rfingers",
}

# BVH namings found in the corpus: cgspeed CMU conversions (MotionBuilder-style names:
# LowerBack/Spine/Spine1, LeftShoulder = clavicle; 3dsMax-style names: lowerback/Chest/
# Chest2, LeftCollar = clavicle, LeftShoulder = upper arm), Bandai-Namco (UpperLeg_L...),
# Xia et al. (deep-motion-editing retarget, MotionBuilder-style) and the PyMO demo. Each
# canonical joint lists candidates in order of preference; the first present in a
# skeleton and not yet taken wins. End sites are named ``<parent>_end`` by the BVH reader.
_BVH_CANDIDATES: dict[str, tuple[str, ...]] = {
    "root": ("Hips", "hip", "Hip", "pelvis", "Pelvis", "Root", "root"),
    "lhip": ("LeftUpLeg", "LeftHip", "lThigh", "LeftThigh", "UpperLeg_L", "l_hip"),
    "lknee": ("LeftLeg", "LeftKnee", "lShin", "LeftShin", "LowerLeg_L", "l_knee"),
    "lankle": ("LeftFoot", "LeftAnkle", "lFoot", "Foot_L", "l_ankle"),
    "ltoes": ("LeftToeBase", "LeftToe", "LeftToes", "Toes_L", "Toe_L", "l_toes"),
    "rhip": ("RightUpLeg", "RightHip", "rThigh", "RightThigh", "UpperLeg_R", "r_hip"),
    "rknee": ("RightLeg", "RightKnee", "rShin", "RightShin", "LowerLeg_R", "r_knee"),
    "rankle": ("RightFoot", "RightAnkle", "rFoot", "Foot_R", "r_ankle"),
    "rtoes": ("RightToeBase", "RightToe", "RightToes", "Toes_R", "Toe_R", "r_toes"),
    "lowerback": ("LowerBack", "Spine", "Spine0", "abdomen", "Chest0"),
    "upperback": ("Spine1", "Chest", "chest1", "Spine"),
    "chest": ("Chest2", "Spine2", "Spine1", "Chest", "chest"),
    "neck": ("lowerneck", "Neck", "Neck1", "neck"),
    "head": ("Head", "head"),
    "headtop": ("Head_end", "head_end", "HeadEnd", "Head_End", "Site_Head"),
    "lclavicle": ("LeftCollar", "LeftShoulder", "lCollar", "Shoulder_L", "l_clavicle"),
    "lshoulder": ("LeftArm", "LeftUpArm", "lShldr", "UpperArm_L", "l_shoulder", "LeftShoulder"),
    "lelbow": ("LeftForeArm", "LeftElbow", "LeftLowArm", "lForeArm", "LowerArm_L", "l_elbow"),
    "lwrist": ("LeftHand", "LeftWrist", "lHand", "Hand_L", "l_wrist"),
    "lfingers": ("LeftHandIndex1", "LFingers", "LeftFingerBase", "LeftHand_end", "LeftHandEnd", "Hand_L_end",
                 "LeftHandFinger1"),
    "rclavicle": ("RightCollar", "RightShoulder", "rCollar", "Shoulder_R", "r_clavicle"),
    "rshoulder": ("RightArm", "RightUpArm", "rShldr", "UpperArm_R", "r_shoulder", "RightShoulder"),
    "relbow": ("RightForeArm", "RightElbow", "RightLowArm", "rForeArm", "LowerArm_R", "r_elbow"),
    "rwrist": ("RightHand", "RightWrist", "rHand", "Hand_R", "r_wrist"),
    "rfingers": ("RightHandIndex1", "RFingers", "RightFingerBase", "RightHand_end", "RightHandEnd", "Hand_R_end",
                 "RightHandFinger1"),
}

# Order in which canonical joints pick their candidates: the trunk top-down (so that
# chest takes Spine1/Chest2 before upperback falls back to Spine), clavicles before
# shoulders (3dsMax-style LeftShoulder is the upper arm only when LeftCollar exists).
_BVH_PICK_ORDER: tuple[str, ...] = (
    "root", "chest", "upperback", "lowerback", "neck", "head", "headtop",
    "lhip", "lknee", "lankle", "ltoes", "rhip", "rknee", "rankle", "rtoes",
    "lclavicle", "lshoulder", "lelbow", "lwrist", "lfingers",
    "rclavicle", "rshoulder", "relbow", "rwrist", "rfingers",
)


def map_asf(joint_names: list[str] | tuple[str, ...]) -> dict[str, int]:
    """Canonical map for an Acclaim (CMU/HDM05) skeleton given its joint names."""
    index = {n: i for i, n in enumerate(joint_names)}
    return {c: index[s] for c, s in _ASF.items() if s in index}


def map_bvh(joint_names: list[str] | tuple[str, ...]) -> dict[str, int]:
    """Canonical map for a BVH skeleton, matching the known namings (case-insensitive)."""
    index = {n.lower(): i for i, n in enumerate(joint_names)}
    if {"lfemur", "rfemur", "lhumerus", "rhumerus"} <= index.keys():  # Acclaim names (BVH written from ASF)
        return map_asf(joint_names)
    out: dict[str, int] = {}
    used: set[int] = set()
    for canon in _BVH_PICK_ORDER:
        # a skeleton already named with the canonical vocabulary maps to itself
        for cand in (*_BVH_CANDIDATES[canon], canon):
            i = index.get(cand.lower())
            # chest/upperback share candidates: never give one joint two canonical names
            if i is not None and i not in used:
                out[canon] = i
                used.add(i)
                break
    return out


def missing_required(canonical: dict[str, int]) -> list[str]:
    """Required canonical joints absent from a canonical map."""
    return [j for j in REQUIRED_JOINTS if j not in canonical]
