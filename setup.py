from glob import glob
import os

from setuptools import find_packages, setup

package_name = 'pg_node'

setup(
    name=package_name,
    version='0.1.0',
    # pg_node alone: the repository's bench/ (benchmarks, soak) and test/ are not installed
    packages=find_packages(include=[package_name, package_name + '.*']),
    package_data={package_name + '.sim': ['models/*.xml', 'models/urdf/*.urdf',
                                          'models/urdf/LICENSE.*',
                                          'models/urdf/meshes/*/*.stl']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        (os.path.join('share', package_name, 'config'),
         glob('config/*.yaml') + glob('config/*.rviz') + glob('config/*.json')),
        (os.path.join('share', package_name, 'config', 'controllers'),
         glob('config/controllers/*.yaml')),
        (os.path.join('share', package_name, 'launch'), glob('launch/*.launch.py')),
        (os.path.join('share', package_name, 'models'), glob('pg_node/sim/models/*.xml')),
        (os.path.join('share', package_name, 'models', 'urdf'),
         glob('pg_node/sim/models/urdf/*.urdf') + glob('pg_node/sim/models/urdf/LICENSE.*')),
        (os.path.join('share', package_name, 'models', 'urdf', 'meshes', 'ur5e'),
         glob('pg_node/sim/models/urdf/meshes/ur5e/*.stl')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='pg_node developers',
    maintainer_email='pg-node@users.noreply.github.com',
    description='Policy-gradient learning for a MuJoCo robot arm over ROS 2.',
    license='Apache-2.0',
    extras_require={'test': ['pytest']},
    entry_points={
        'console_scripts': [
            'sim_node = pg_node.ros.sim_node:main',
            'actor_node = pg_node.ros.actor_node:main',
            'critic_node = pg_node.ros.critic_node:main',
            'learner_node = pg_node.ros.learner_node:main',
            'replay_node = pg_node.ros.replay_node:main',
            'policy_node = pg_node.ros.policy_node:main',
            'pybullet_node = pg_node.ros.pybullet_node:main',
            'sim_and_actor = pg_node.ros.sim_and_actor:main',
            'critic_and_learner = pg_node.ros.critic_and_learner:main',
            # python -m pg_node as an executable: ros2 run pg_node pg_node train, and the
            # launch file's supervised:=true, in the Python pg_node was installed with
            'pg_node = pg_node.tools.cli:main',
        ],
    },
)
