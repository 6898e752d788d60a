"""The installed rviz2 config shows the URDF from /robot_description in the URDF's root frame."""
from pathlib import Path
import xml.etree.ElementTree as ET

import yaml


def _share(package: str) -> Path:
    from ament_index_python.packages import get_package_share_directory
    return Path(get_package_share_directory(package))


def test_rviz_config_shows_the_robot_model_in_the_root_frame():
    config = yaml.safe_load((_share('cartpole_analysis') / 'config' / 'cartpole.rviz').read_text())
    manager = config['Visualization Manager']
    urdf = ET.parse(_share('cartpole_sim') / 'urdf' / 'cartpole.urdf').getroot()
    links = {link.get('name') for link in urdf.findall('link')}
    children = {joint.find('child').get('link') for joint in urdf.findall('joint')}
    assert manager['Global Options']['Fixed Frame'] == 'base_link'
    assert links - children == {'base_link'}
    displays = {d['Class']: d for d in manager['Displays']}
    model = displays['rviz_default_plugins/RobotModel']
    assert model['Enabled'] and model['Description Source'] == 'Topic'
    topic = model['Description Topic']
    assert topic['Value'] == '/robot_description'
    # robot_state_publisher offers /robot_description transient local: a late rviz2 gets it
    assert topic['Durability Policy'] == 'Transient Local'
    assert model['TF Prefix'] == ''
    assert displays['rviz_default_plugins/TF']['Enabled']


def test_foxglove_layout_is_installed():
    assert (_share('cartpole_analysis') / 'config' / 'foxglove_layout.json').is_file()
