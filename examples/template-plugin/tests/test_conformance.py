from mocapflow_template.plugin import JointSpeed, SlidingWindow

from mocapflow.framework.testing import parametrize_with_checks, synthetic_motion


@parametrize_with_checks([JointSpeed, SlidingWindow])
def test_conformance(component_class, check):
    check(component_class)


def test_speed_of_a_standing_pose_is_zero():
    m = synthetic_motion(10)
    still = m.with_arrays(
        rotations=m.rotations[:1].repeat(10, 0), root_translation=m.root_translation[:1].repeat(10, 0)
    )
    assert JointSpeed().transform(still).max() == 0.0
