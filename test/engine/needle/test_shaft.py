"""The needle's shape (engine/needle/shaft.py): a rigid needle's base and tip in its base frame, a
flexible one's rod nodes each with its segment's frame."""
import numpy as np


def test_a_flexible_needles_shape_is_its_rod_and_its_frames():
    """The shape of a bent rod: its nodes, each with the frame of its segment (+z along it), the
    tip's frame last; a rigid needle's: its base and tip in the base frame."""
    from tissue_sim_ros.engine.needle.pose import rotation_matrix
    from tissue_sim_ros.engine.scene.scene import Scene
    rigid = Scene.from_file().needle
    positions, quaternions = np.empty((rigid.shape_size, 3)), np.empty((rigid.shape_size, 4))
    rigid.write_shape(positions, quaternions)
    assert rigid.shape_size == 2 and np.allclose(positions[-1], rigid.tip, atol=1e-12)
    assert np.allclose(positions[0], rigid.position) and np.allclose(quaternions, rigid.orientation)
    flexible = Scene.from_file(sets=['needle.flexible=true', 'needle.rod_segments=12']).needle
    rod = flexible.rod
    s = np.linspace(0.0, 1.0, 13)
    bent = flexible.position + np.outer(s * 0.15, flexible.axis) + np.outer(0.01 * s ** 2, flexible.rotation[:, 0])
    rod.nodes[:] = bent
    flexible.n_points = 5                         # the rod holds its shape only while the tissue holds it
    from tissue_sim_ros.engine.needle.rod import transport_frames
    transport_frames(rod.nodes, flexible.rotation, rod.frames)
    positions, quaternions = np.empty((13, 3)), np.empty((13, 4))
    flexible.write_shape(positions, quaternions)
    assert flexible.shape_size == 13 and np.array_equal(positions, bent)
    for k in range(12):
        frame = rotation_matrix(quaternions[k])
        tangent = (bent[k + 1] - bent[k]) / np.linalg.norm(bent[k + 1] - bent[k])
        assert np.allclose(frame[:, 2], tangent, atol=1e-12)
