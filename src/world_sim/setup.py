from glob import glob

from setuptools import find_packages, setup

package_name = 'world_sim'

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
    description='The physical world of uav-flock: MAP dynamics, ground users, association, metrics, and the batch simulator.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'world_sim_node = world_sim.world_node:main',
        ],
    },
)
