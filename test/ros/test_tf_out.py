"""TF out (ros/tf_out.py): a rigid needle's tip is a static transform on its base, the needle's
length along +z; a flexible needle's tip, which the rod's bending moves off the base's axis, goes
on /tf every tick, where the engine put it."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pytest.importorskip('rclpy')
pytest.importorskip('tf2_msgs')

from support.flexible import SPEED, phantom  # noqa: E402
from tissue_sim_ros.analysis.steering import insert_path  # noqa: E402
from tissue_sim_ros.bench.steering import needle_sets  # noqa: E402
from tissue_sim_ros.ros.tf_out import TfFrames, needle_frames  # noqa: E402


def _frames_and_messages(scene):
    needle = scene.needle
    positions, quaternions = np.zeros((needle.shape_size, 3)), np.zeros((needle.shape_size, 4))
    needle.write_shape(positions, quaternions)
    frames = TfFrames('world', needle_frames('needle', scene.needle_names), [needle.geometry.length_m], (),
                      [needle.rod is not None])
    static = {t.child_frame_id: t for t in frames.static_msg(0).transforms}
    dynamic = {t.child_frame_id: t for t in frames.dynamic_msg(
        0, [needle.position], [needle.orientation], np.zeros((0, 3)), [(positions, quaternions)]).transforms}
    return static, dynamic


def _xyz(vector):
    return np.array([vector.x, vector.y, vector.z])


def test_a_bent_needles_tip_frame_is_where_the_engine_put_the_tip():
    scene = phantom(*needle_sets('20 G nitinol', 'bevel', 0.0))
    insert_path(scene, scene.start_gap_m + 0.006, SPEED)
    needle = scene.needle
    static, dynamic = _frames_and_messages(scene)
    assert 'needle_tip' not in static and static == {}
    tip = dynamic['needle_tip']
    assert tip.header.frame_id == 'world'
    np.testing.assert_allclose(_xyz(tip.transform.translation), needle.tip, rtol=0, atol=1e-12)
    on_axis = needle.position + needle.geometry.length_m * needle.rotation[:, 2]
    assert np.linalg.norm(needle.tip - on_axis) > 1e-7          # bent: not where a rigid tip is


def test_a_rigid_needles_tip_frame_composed_with_its_base_is_its_tip():
    scene = phantom()
    insert_path(scene, scene.start_gap_m + 0.005, SPEED)
    needle = scene.needle
    static, dynamic = _frames_and_messages(scene)
    assert 'needle_tip' not in dynamic
    base, tip = dynamic['needle'].transform, static['needle_tip'].transform
    rotation = Rotation.from_quat([base.rotation.x, base.rotation.y, base.rotation.z, base.rotation.w])
    np.testing.assert_allclose(_xyz(base.translation) + rotation.apply(_xyz(tip.translation)), needle.tip,
                               rtol=0, atol=1e-12)
