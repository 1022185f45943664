"""Declaring the node's parameters with rclpy (ros/parameter_declaration.py): every parameter with
its default, read-only, with its range or choices in its descriptor; an override rclpy refuses
becomes one ConfigError naming the parameter. Truth: the parameter table (ros/parameters.py) and
what rclpy itself reports back about the node's parameters."""
import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.parameter import Parameter  # noqa: E402

from support.ros_clients import DOMAIN_ID  # noqa: E402
from tissue_sim_ros.errors import ConfigError  # noqa: E402
from tissue_sim_ros.ros.parameter_declaration import declare_parameters  # noqa: E402
from tissue_sim_ros.ros.parameters import PARAMETERS  # noqa: E402


@pytest.fixture
def make_node():
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN_ID)
    made = []

    def make(*overrides):
        node = rclpy.create_node('declared', context=ctx, parameter_overrides=list(overrides))
        made.append(node)
        return node
    yield make
    for node in made:
        node.destroy_node()
    rclpy.shutdown(context=ctx)


def test_every_parameter_is_declared_read_only_with_its_default_and_bounds(make_node):
    node = make_node()
    values = declare_parameters(node)
    assert values == {p.name: p.default for p in PARAMETERS}
    for p, descriptor in zip(PARAMETERS, node.describe_parameters([p.name for p in PARAMETERS])):
        assert descriptor.read_only and descriptor.description.startswith(p.description)
        ranges = list(descriptor.floating_point_range) + list(descriptor.integer_range)
        if p.low is None:
            assert not ranges, p.name
        else:
            assert (ranges[0].from_value, ranges[0].to_value) == (p.low, p.high), p.name
        assert all(choice in descriptor.additional_constraints for choice in p.choices), p.name


def test_an_override_rclpy_refuses_is_one_error_naming_the_parameter(make_node):
    ranged = next(p for p in PARAMETERS if isinstance(p.default, float) and p.low is not None)
    with pytest.raises(ConfigError, match=f'parameter {ranged.name}: .*expected {ranged.low} <= value <= {ranged.high}'):
        declare_parameters(make_node(Parameter(ranged.name, value=float(ranged.high) * 2 + 1.0)))
    with pytest.raises(ConfigError, match=f'parameter {ranged.name}: .*a floating-point number .*write 50.0, not 50'):
        declare_parameters(make_node(Parameter(ranged.name, value=int(ranged.low) + 1)))
