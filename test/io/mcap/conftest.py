"""The MCAP tests' logs: every node topic recorded five times, and good poses with a bad payload
after every third (module scope)."""

import pytest

pytest.importorskip('rclpy')

from rclpy.serialization import serialize_message  # noqa: E402

from support.bad_payloads import _bad_payloads, _pose  # noqa: E402
from support.mcap_samples import PERIOD, POSE, T0, WRENCH, _record  # noqa: E402
from tissue_sim_ros.io import mcap as ml  # noqa: E402
from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402


@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp('rec') / 'run.mcap'
    return path, _record(path)


@pytest.fixture(scope='module')
def log_with_bad_poses(tmp_path_factory):
    """Good poses and wrenches with a bad payload on needle/pose after every third good pose."""
    path = tmp_path_factory.mktemp('bad') / 'bad.mcap'
    bad = list(_bad_payloads().items())
    good_times, bad_times = [], []
    with ml.McapRecorder(path, metadata={'scene': 's'}) as rec:
        rec.add_topic('needle/pose', POSE, {})
        rec.add_topic('needle/wrench', WRENCH, {})
        k = 0
        for i in range(30):
            t = T0 + i * PERIOD
            rec.write('needle/pose', serialize_message(_pose(i)), t)
            good_times.append(t)
            rec.write('needle/wrench',
                      serialize_message(cv.wrench_msg([i, 0, 0], [0, 0, 0], 'needle', t)), t + 1)
            if i % 3 == 2 and k < len(bad):
                rec.write('needle/pose', bad[k][1], t + 2)
                bad_times.append(t + 2)
                k += 1
    assert k == len(bad)
    return path, good_times, bad_times, bad
