"""ros2 launch tissue_sim_ros tissue_sim.launch.py [scene:=FILE] [params_file:=FILE] [namespace:=NS]
[use_sim_time:=true] [recording_directory:=DIR] [input_source:=topic|tf] [tf_frame:=tool0]

The tissue_sim node with the package's parameter file (or yours), a scene, a namespace, sim time, a
recording directory and the needle's pose source: needle/pose, or the robot's TF frame ``tf_frame``.
Wait for it with the latched ``~/ready`` topic (true once it ticks). RViz: ``rviz2 -d
$(ros2 pkg prefix tissue_sim_ros)/share/tissue_sim_ros/rviz/tissue_sim.rviz``.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

ARGUMENTS = {
    'scene': ('', 'scene YAML; empty = the packaged config/liver_sample.yaml'),
    'params_file': (os.path.join(get_package_share_directory('tissue_sim_ros'), 'config', 'tissue_sim.yaml'),
                    'the node parameter file'),
    'namespace': ('', 'the namespace of the node and its topics'),
    'use_sim_time': ('false', 'follow /clock (a bag played with --clock)'),
    'recording_directory': ('', 'where the MCAP log goes; empty = no recording'),
    'input_source': ('topic', "the needle's pose: topic (needle/pose) or tf (the frame tf_frame)"),
    'tf_frame': ('tool0', 'with input_source tf: the robot frame that carries the needle'),
}


def generate_launch_description():
    arguments = [DeclareLaunchArgument(name, default_value=default, description=text)
                 for name, (default, text) in ARGUMENTS.items()]
    node = Node(
        package='tissue_sim_ros', executable='tissue_sim_node', name='tissue_sim',
        namespace=LaunchConfiguration('namespace'), output='screen',
        parameters=[LaunchConfiguration('params_file'), {
            'scene_file': LaunchConfiguration('scene'),
            'use_sim_time': ParameterValue(LaunchConfiguration('use_sim_time'), value_type=bool),
            'recording.directory': LaunchConfiguration('recording_directory'),
            'input.source': LaunchConfiguration('input_source'),
            'input.tf_frame': LaunchConfiguration('tf_frame'),
        }])
    return LaunchDescription(arguments + [node])
