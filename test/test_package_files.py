"""What the package installs for a ROS user: package.xml names every ROS package the code imports,
the launch file declares its arguments and runs the node with them (read with ast: there is no
launch package here), and the RViz and Foxglove views name only topics and frames the node has."""

import ast
import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]


def _imported_top_level(paths):
    names = set()
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names.update(alias.name.split('.')[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                names.add(node.module.split('.')[0])
    return names


def _ros_packages():
    """Every ROS package installed here (the ament index of the environment)."""
    import sys

    index = Path(sys.prefix) / 'share' / 'ament_index' / 'resource_index' / 'packages'
    return {p.name for p in index.iterdir()} if index.is_dir() else set()


def test_package_xml_lists_every_ros_package_the_code_imports():
    depends = {e.text for e in ET.parse(ROOT / 'package.xml').getroot() if e.tag.endswith('depend')}
    ros = _ros_packages()
    assert {'rclpy', 'geometry_msgs', 'tf2_msgs', 'tissue_sim_msgs'} <= ros
    code = sorted((ROOT / 'tissue_sim_ros').rglob('*.py')) + [ROOT / 'launch' / 'tissue_sim.launch.py']
    imported = {name for name in _imported_top_level(code) if name in ros | {'launch', 'launch_ros'}}
    assert imported - depends == set()
    # every key a rosdep key or a ROS package; the pip-only ones are requirements.txt's (say so)
    assert not [d for d in depends if d.endswith('-pip')]
    pinned = (ROOT / 'requirements.txt').read_text()
    assert 'numba==' in pinned and 'mcap==' in pinned


def _launch_file():
    return ast.parse((ROOT / 'launch' / 'tissue_sim.launch.py').read_text())


def _assigned(tree, name):
    return next(n.value for n in tree.body if isinstance(n, ast.Assign) and n.targets[0].id == name)


def test_the_launch_file_declares_its_arguments_and_passes_them_to_one_node():
    tree = _launch_file()
    names = [ast.literal_eval(k) for k in _assigned(tree, 'ARGUMENTS').keys]
    assert names == ['scene', 'params_file', 'namespace', 'use_sim_time', 'recording_directory',
                     'input_source', 'tf_frame']
    defaults = {ast.literal_eval(k): v.elts[0] for k, v in zip(_assigned(tree, 'ARGUMENTS').keys,
                                                               _assigned(tree, 'ARGUMENTS').values)}
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, 'id', '') == 'Node']
    assert len(calls) == 1
    keywords = {k.arg: k.value for k in calls[0].keywords}
    assert ast.literal_eval(keywords['package']) == 'tissue_sim_ros'
    assert ast.literal_eval(keywords['executable']) == 'tissue_sim_node'
    assert ast.literal_eval(keywords['name']) == 'tissue_sim'
    assert ast.unparse(keywords['namespace']) == "LaunchConfiguration('namespace')"
    # the parameter file first, then the arguments given: each sets a parameter the node has, and
    # an empty one (every default) sets nothing, so a study's parameter file keeps its values
    assert ast.unparse(keywords['parameters']) == "[LaunchConfiguration('params_file'), overrides]"
    parameter_of = ast.literal_eval(_assigned(tree, 'PARAMETER_OF'))
    from tissue_sim_ros.ros.parameters import PARAMETERS

    declared = {p.name for p in PARAMETERS} | {'use_sim_time'}
    assert set(parameter_of.values()) <= declared
    assert set(parameter_of) | {'params_file', 'namespace'} == set(names)
    assert all(ast.literal_eval(defaults[name]) == '' for name in parameter_of)
    # the node's defaults for them (the packaged parameter file: what an empty argument leaves)
    params = yaml.safe_load((ROOT / 'config' / 'tissue_sim.yaml').read_text())['tissue_sim']['ros__parameters']
    assert params['input']['source'] == 'topic' and params['recording']['directory'] == ''


@pytest.fixture(scope='module')
def node_names():
    """The node's topics (from its topic table) and frames (its parameters' defaults, the scene's
    frame, the TF frames it broadcasts)."""
    from tissue_sim_ros.engine.scene.scene import Scene
    from tissue_sim_ros.ros.messages.topics import NODE_TOPIC_TYPES
    from tissue_sim_ros.ros.parameters import NODE_NAME, PARAMETERS
    from tissue_sim_ros.ros.tf_out import needle_frames

    defaults = {p.name: p.default for p in PARAMETERS}
    scene_frame = 'world'  # Scene.from_file's mesh frame for the packaged scene
    assert Scene.__init__.__defaults__[-2] == scene_frame
    topics = {
        ('/' + t if not t.startswith('/') else t).replace('/~', f'/{NODE_NAME}') for t in NODE_TOPIC_TYPES
    }
    frames = {defaults['frame_id'] or scene_frame} | {
        f for pair in needle_frames(defaults['needle_frame_id'], ['needle']) for f in pair
    }
    return topics, frames


def test_the_rviz_configuration_names_only_topics_and_frames_of_the_node(node_names):
    topics, frames = node_names
    config = yaml.safe_load((ROOT / 'rviz' / 'tissue_sim.rviz').read_text())
    manager = config['Visualization Manager']
    displays = manager['Displays']
    named_topics = {d['Topic']['Value'] for d in displays if 'Topic' in d}
    named_frames = {manager['Global Options']['Fixed Frame'], manager['Views']['Current']['Target Frame']} | {
        d['Reference Frame'] for d in displays if d.get('Reference Frame', '<Fixed Frame>') != '<Fixed Frame>'
    }
    assert named_topics and named_topics <= topics
    assert named_frames <= frames
    kinds = {d['Class'].split('/')[-1] for d in displays}
    assert {'TF', 'Marker', 'PointCloud2', 'Wrench', 'PoseArray'} <= kinds  # mesh, cloud, wrench, targets, TF
    from tissue_sim_ros.ros.messages.conversions import POINT_CLOUD_FIELDS

    channels = {d['Channel Name'] for d in displays if 'Channel Name' in d}
    assert channels and channels <= set(POINT_CLOUD_FIELDS)  # the cloud's colour is a field it has


def test_the_foxglove_layout_names_only_topics_and_frames_of_the_node(node_names):
    topics, frames = node_names
    layout = json.loads((ROOT / 'foxglove' / 'tissue_sim.json').read_text())
    text = json.dumps(layout['configById'])
    named_topics = set(re.findall(r'"(/[a-z_/]+?)(?:\.|")', text))
    named_frames = set(re.findall(r'frame:([a-z_]+)', text)) | {
        c['followTf'] for c in layout['configById'].values() if 'followTf' in c
    }
    assert named_topics and named_topics <= topics, named_topics - topics
    assert named_frames <= frames
    panels = set(layout['configById'])

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node['first']) + leaves(node['second'])

    assert set(leaves(layout['layout'])) == panels
