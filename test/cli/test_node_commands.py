"""The commands that run or drive the node (cli/node_commands.py): a node parameter given on the
command line is NAME:=VALUE, as the node's --ros-args -p takes it, or one error line naming it."""
import argparse

import pytest

from tissue_sim_ros.cli.node_commands import _node_parameter


@pytest.mark.parametrize('text, passed', [('prediction.max_error:=0.02', 'prediction.max_error:=0.02'),
                                          (' publish_rate_hz := 50.0 ', 'publish_rate_hz:=50.0'),
                                          ('scene_file:=/a/b:c.yaml', 'scene_file:=/a/b:c.yaml')])
def test_a_node_parameter_reaches_the_node_as_name_colon_equals_value(text, passed):
    assert _node_parameter(text) == passed


@pytest.mark.parametrize('text', ['prediction.max_error=0.02', ':=1', 'publish_rate_hz:=', 'name'])
def test_anything_else_is_refused_naming_it(text):
    with pytest.raises(argparse.ArgumentTypeError, match=f'{text!r}: expected NAME:=VALUE'):
        _node_parameter(text)
