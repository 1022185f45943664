"""ros2 launch tissue_sim_ros tissue_sim.launch.py [scene:=FILE] [params_file:=FILE] [namespace:=NS]
[use_sim_time:=true] [recording_directory:=DIR] [input_source:=topic|tf] [tf_frame:=tool0]

The tissue_sim node with the package's parameter file (or yours), a scene, a namespace, sim time, a
recording directory and the needle's pose source: needle/pose, or the robot's TF frame ``tf_frame``.
An argument left empty leaves the parameter file's value (or the node's default) as it is, so a
study's parameter file is not overridden by arguments it was not given. Wait for the node with the
latched ``~/ready`` topic (true once it ticks). RViz: ``rviz2 -d
$(ros2 pkg prefix tissue_sim_ros)/share/tissue_sim_ros/rviz/tissue_sim.rviz``.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

ARGUMENTS = {
    'scene': ('', 'scene YAML; empty: the parameter file\'s scene_file (the packaged liver sample)'),
    'params_file': (os.path.join(get_package_share_directory('tissue_sim_ros'), 'config', 'tissue_sim.yaml'),
                    'the node parameter file'),
    'namespace': ('', 'the namespace of the node and its topics'),
    'use_sim_time': ('', 'true: follow /clock (a bag played with --clock); empty: the parameter file\'s'),
    'recording_directory': ('', 'where the MCAP log goes; empty: the parameter file\'s (none: no log)'),
    'input_source': ('', "the needle's pose: topic (needle/pose) or tf (the frame tf_frame); empty: "
                         "the parameter file's (topic)"),
    'tf_frame': ('', "with input source tf: the robot frame that carries the needle, e.g. tool0; empty: "
                     "the parameter file's"),
}
#: the node parameter each argument sets when it is not empty (params_file and namespace: the node's)
PARAMETER_OF = {
    'scene': 'scene_file',
    'use_sim_time': 'use_sim_time',
    'recording_directory': 'recording.directory',
    'input_source': 'input.source',
    'tf_frame': 'input.tf_frame',
}


def _node(context):
    overrides = {}
    for argument, parameter in PARAMETER_OF.items():
        value = LaunchConfiguration(argument).perform(context)
        if value:
            overrides[parameter] = value.lower() == 'true' if parameter == 'use_sim_time' else value
    return [Node(package='tissue_sim_ros', executable='tissue_sim_node', name='tissue_sim',
                 namespace=LaunchConfiguration('namespace'), output='screen',
                 parameters=[LaunchConfiguration('params_file'), overrides])]


def generate_launch_description():
    arguments = [DeclareLaunchArgument(name, default_value=default, description=text)
                 for name, (default, text) in ARGUMENTS.items()]
    return LaunchDescription(arguments + [OpaqueFunction(function=_node)])
