from setuptools import find_packages, setup

package_name = 'uav_flock_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='uav-flock developers',
    maintainer_email='dev@uav-flock.invalid',
    description='ROS 2 plumbing shared by every uav-flock node: QoS, executor, message conversions, process checks.',
    license='Apache-2.0',
)
