from glob import glob

from setuptools import find_packages, setup

package_name = 'uav_agent'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='uav-flock developers',
    maintainer_email='dev@uav-flock.invalid',
    description='One MAP of the formation: the per-MAP control law and mode switch, and its rclpy node.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'uav_agent_node = uav_agent.agent_process:main',
        ],
    },
)
