from glob import glob

from setuptools import find_packages, setup

package_name = 'ur_rg2_sim'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        # The arm's meshes, package://ur_rg2_sim/meshes/MODEL/LINK.obj (meshes/PROVENANCE.md).
        ('share/' + package_name + '/meshes', ['meshes/PROVENANCE.md']),
        ('share/' + package_name + '/meshes/ur3', glob('meshes/ur3/*.obj')),
        ('share/' + package_name + '/meshes/ur5', glob('meshes/ur5/*.obj')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='UR RG2 sim maintainers',
    maintainer_email='maintainers@ur-rg2-sim.invalid',
    description='Simulated UR arm with an OnRobot RG2 gripper and an RGB-D camera (pybullet).',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'sim = ur_rg2_sim.entry:sim',
        ],
    },
)
