"""ament_python build of tissue_sim_ros (colcon build / pip install -e . both use this)."""
import re
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

package_name = 'tissue_sim_ros'
here = Path(__file__).resolve().parent
# package.xml holds the version; the Python package reads it back through importlib.metadata.
version = re.search(r'<version>([^<]+)</version>', (here / 'package.xml').read_text()).group(1)

setup(
    name=package_name,
    version=version,
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*')),
        ('share/' + package_name + '/msg_examples', glob('msg_examples/*')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        ('share/' + package_name + '/rviz', glob('rviz/*.rviz')),
        ('share/' + package_name + '/foxglove', glob('foxglove/*.json')),
        ('share/' + package_name + '/data/okamura2004_bovine_liver', glob('data/okamura2004_bovine_liver/*')),
    ],
    python_requires='>=3.12',    # ROS 2 Jazzy's; warnings' skip_file_prefixes, tarfile's filter
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},  # so that `colcon test` runs pytest, not unittest
    zip_safe=True,
    maintainer='tissue_sim_ros developers',
    maintainer_email='dev@tissue-sim-ros.invalid',
    description='Real-time tensor-mass FEM soft-tissue simulation for needle insertion, ROS 2 node.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'tissue_sim_node = tissue_sim_ros.cli.node_script:main',
            'tissue-sim = tissue_sim_ros.cli:main',
        ],
    },
)
