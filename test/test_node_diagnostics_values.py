"""/diagnostics before anything happened: every value that does not exist yet says so; none is
NaN (tools that parse diagnostics must not meet it)."""
import math

import pytest

pytest.importorskip('rclpy')
from test_node import _private_ros, harness  # noqa: E402,F401 - the fixtures


def _numbers_or_words(values):
    """{key: the value as a float, or the text when it is not a number}."""
    out = {}
    for key, value in values.items():
        try:
            out[key] = float(value)
        except ValueError:
            out[key] = value
    return out


def test_no_diagnostic_value_is_nan_before_the_first_pose(harness):
    h = harness(**{'prediction.workers': 1})
    statuses = h.diagnostics_now()
    assert {'tissue_sim: engine', 'tissue_sim: input'} <= set(statuses)
    for name, (_, _, values) in statuses.items():
        for key, value in _numbers_or_words(values).items():
            assert not (isinstance(value, float) and math.isnan(value)), f'{name} {key} = {values[key]!r}'
            assert str(values[key]).lower() not in ('nan', '-nan', 'inf', '-inf'), f'{name} {key}'
    inputs = statuses['tissue_sim: input'][2]
    assert inputs['latency_ms_p50'] == inputs['latency_ms_p99'] == inputs['last_pose_age_s'] == 'none yet'
    if 'tissue_sim: predictions' in statuses:
        assert statuses['tissue_sim: predictions'][2]['real_time_factor_median'] == 'none yet'


def test_a_figure_that_does_not_exist_is_never_written_as_nan():
    from tissue_sim_ros.ros.messages.conversions import diagnostic_array_msg
    msg = diagnostic_array_msg(0, [('x', 'OK', '', {'a': float('nan'), 'b': 1.5, 'c': float('inf')})])
    assert [kv.value for kv in msg.status[0].values] == ['not available', '1.5', 'not available']


def test_node_bench_reads_a_figure_that_does_not_exist_as_nan():
    """node-bench's figures from the node's diagnostics: 'none yet' is a missing number, not an
    error (it read every value as a float)."""
    from types import SimpleNamespace

    from tissue_sim_ros.bench.node_bench_figures import diagnostic_figures
    from tissue_sim_ros.ros.messages.conversions import diagnostic_array_msg
    msg = diagnostic_array_msg(0, [('tissue_sim: engine', 'OK', '', {'budget_use': 'none yet', 'lag_s': 0.001,
                                                                     'ticks': 10}),
                                   ('tissue_sim: predictions', 'OK', '', {'real_time_factor_median': 'none yet'})])
    figures = diagnostic_figures([SimpleNamespace(header=msg.header, status=msg.status)])
    assert math.isnan(figures['budget_use']) and math.isnan(figures['prediction_real_time_factor'])
    assert figures['lag_s'] == 0.001 and figures['ticks'] == 10
