"""The ament_python layout, checked by building the package with colcon into a temp dir."""
from pathlib import Path
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

REPO = Path(__file__).resolve().parent.parent
EXECUTABLES = ('sim_node', 'actor_node', 'critic_node', 'learner_node', 'replay_node')
SOURCES = ('package.xml', 'setup.py', 'setup.cfg', 'resource', 'pg_node', 'config', 'launch')


@pytest.fixture(scope='module')
def install(tmp_path_factory):
    ws = tmp_path_factory.mktemp('ws')
    src = ws / 'src' / 'pg_node'
    src.mkdir(parents=True)
    for name in SOURCES:
        path = REPO / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns('__pycache__'))
        else:
            shutil.copy2(path, src / name)
    colcon = Path(sys.executable).parent / 'colcon'
    res = subprocess.run([str(colcon), '--log-base', str(ws / 'log'), 'build',
                          '--base-paths', str(ws / 'src'), '--build-base', str(ws / 'build'),
                          '--install-base', str(ws / 'install')],
                         cwd=ws, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    return ws / 'install' / 'pg_node'


def test_executables_in_lib(install):
    for exe in EXECUTABLES:
        path = install / 'lib' / 'pg_node' / exe
        assert path.is_file(), f'{path} missing: ros2 run pg_node {exe} would fail'
        text = path.read_text()
        assert f"'console_scripts', '{exe}'" in text or exe in text


def test_share_holds_package_xml_config_launch_models(install):
    share = install / 'share' / 'pg_node'
    assert (share / 'package.xml').is_file()
    assert (share / 'config' / 'pg_node.yaml').is_file()
    assert (share / 'launch' / 'train.launch.py').is_file()
    models = {p.name for p in (share / 'models').glob('*.xml')}
    assert models >= {'reacher2.xml', 'arm5_3d.xml'}
    assert (install / 'share' / 'ament_index' / 'resource_index' / 'packages'
            / 'pg_node').is_file()


def test_installed_package_finds_its_share_dir_and_runs(install, tmp_path):
    """An installed entry point imports, and its share dir is found through ament_index."""
    site = next((install / 'lib').glob('python3*/site-packages'))
    env = {'PATH': '/usr/bin:/bin', 'PYTHONPATH': str(site),
           'AMENT_PREFIX_PATH': f'{install}:{sys.prefix}',
           'LD_LIBRARY_PATH': ''}
    code = ('import pg_node.common.paths as p; print(p.default_config()); '
            'import pg_node.ros.sim_node, pg_node.ros.actor_node, pg_node.ros.critic_node, '
            'pg_node.ros.learner_node, pg_node.ros.replay_node')
    res = subprocess.run([sys.executable, '-c', code], env=env, cwd=tmp_path,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == str(install / 'share' / 'pg_node' / 'config' / 'pg_node.yaml')


def test_package_xml_is_format_3_and_declares_dependencies():
    root = ET.parse(REPO / 'package.xml').getroot()
    assert root.tag == 'package' and root.get('format') == '3'
    assert root.findtext('name') == 'pg_node'
    deps = {e.text for e in root.iter('exec_depend')}
    assert {'rclpy', 'std_msgs', 'sensor_msgs', 'geometry_msgs', 'visualization_msgs',
            'diagnostic_msgs', 'rosgraph_msgs', 'std_srvs', 'rcl_interfaces'} <= deps
    assert root.find('export/build_type').text == 'ament_python'
    assert {'ament_flake8', 'ament_pep257'} <= {e.text for e in root.iter('test_depend')}


def test_launch_file_names_every_training_executable():
    text = (REPO / 'launch' / 'train.launch.py').read_text()
    compile(text, 'train.launch.py', 'exec')
    for exe in ('sim_node', 'actor_node', 'critic_node', 'learner_node'):
        assert f"executable='{exe}'" in text
