from glob import glob

from setuptools import find_packages, setup

package_name = 'uav_flock_tools'

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
    description='Command-line tools of uav-flock: simulation runs, paper figures, plots.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'uav-flock-cli = uav_flock_tools.cli:main',
            'uav_flock_recorder = uav_flock_tools.recorder:main',
            'uav_flock_viewer = uav_flock_tools.viewer:main',
        ],
    },
)
