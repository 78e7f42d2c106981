"""The built-in skeleton naming dialects, registered through ``register_joint_maps``:
``acclaim`` (ASF/AMC skeletons of CMU and HDM05), ``acclaim_bvh`` (BVH files written from them) and
``bvh_common`` (the BVH namings found in public corpora). A plugin adds a dialect the same
way (see :class:`mocapflow.framework.joints.JointMap`)."""

from __future__ import annotations

from mocapflow.framework.joints import CANONICAL_JOINTS, JointMap

# Acclaim ASF skeletons (CMU and HDM05 share bone names). A skeleton joint sits at the
# *start* of the ASF bone of the same name (see asf_amc.py), so the knee
# is the start of the tibia and the wrist the start of the "wrist" bone.
_ASF = {
    "root": "root",
    "lhip": "lfemur",
    "lknee": "ltibia",
    "lankle": "lfoot",
    "ltoes": "ltoes",
    "rhip": "rfemur",
    "rknee": "rtibia",
    "rankle": "rfoot",
    "rtoes": "rtoes",
    "lowerback": "lowerback",
    "upperback": "upperback",
    "chest": "thorax",
    "neck": "lowerneck",
    "head": "head",
    "headtop": "head_end",
    "lclavicle": "lclavicle",
    "lshoulder": "lhumerus",
    "lelbow": "lradius",
    "lwrist": "lwrist",
    "lfingers": "lfingers",
    "rclavicle": "rclavicle",
    "rshoulder": "rhumerus",
    "relbow": "rradius",
    "rwrist": "rwrist",
    "rfingers": "rfingers",
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
    "lfingers": (
        "LeftHandIndex1",
        "LFingers",
        "LeftFingerBase",
        "LeftHand_end",
        "LeftHandEnd",
        "Hand_L_end",
        "LeftHandFinger1",
    ),
    "rclavicle": ("RightCollar", "RightShoulder", "rCollar", "Shoulder_R", "r_clavicle"),
    "rshoulder": ("RightArm", "RightUpArm", "rShldr", "UpperArm_R", "r_shoulder", "RightShoulder"),
    "relbow": ("RightForeArm", "RightElbow", "RightLowArm", "rForeArm", "LowerArm_R", "r_elbow"),
    "rwrist": ("RightHand", "RightWrist", "rHand", "Hand_R", "r_wrist"),
    "rfingers": (
        "RightHandIndex1",
        "RFingers",
        "RightFingerBase",
        "RightHand_end",
        "RightHandEnd",
        "Hand_R_end",
        "RightHandFinger1",
    ),
}

# Order in which canonical joints pick their candidates: the trunk top-down (so that
# chest takes Spine1/Chest2 before upperback falls back to Spine), clavicles before
# shoulders (3dsMax-style LeftShoulder is the upper arm only when LeftCollar exists).
_BVH_TRUNK = ("root", "chest", "upperback", "lowerback", "neck", "head", "headtop")
_BVH_PICK_ORDER: tuple[str, ...] = (*_BVH_TRUNK, *(j for j in CANONICAL_JOINTS if j not in _BVH_TRUNK))


#: Acclaim names, exact (ASF bone names are case-sensitive identifiers).
# self-named: an ASF written from another rig (mocapflow's AMC export of a BVH/FBX/glTF take
# or a canonical skeleton) names its bones by the canonical joints, after any Acclaim bone
ACCLAIM = JointMap(
    "acclaim",
    {c: (s,) for c, s in _ASF.items()},
    formats=("amc",),
    case_sensitive=True,
    pick_order=CANONICAL_JOINTS,
    self_named=True,
)

#: BVH files whose skeleton was written from an ASF, recognised by the Acclaim limb bones.
ACCLAIM_BVH = JointMap(
    "acclaim_bvh",
    ACCLAIM.candidates,
    formats=("bvh",),
    signature=frozenset({"lfemur", "rfemur", "lhumerus", "rhumerus"}),
    case_sensitive=True,
    pick_order=CANONICAL_JOINTS,
)

#: The common BVH namings, case-insensitive, falling back to the canonical names themselves.
BVH_COMMON = JointMap("bvh_common", _BVH_CANDIDATES, formats=("bvh",), pick_order=_BVH_PICK_ORDER, self_named=True)

JOINT_MAPS: tuple[JointMap, ...] = (ACCLAIM, ACCLAIM_BVH, BVH_COMMON)
