"""Install the ur_rg2_teleop ament_python package."""

from setuptools import find_packages, setup

package_name = 'ur_rg2_teleop'

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
    maintainer='UR RG2 sim maintainers',
    maintainer_email='maintainers@ur-rg2-sim.invalid',
    description='Terminal keyboard teleoperation for the UR + RG2 simulation.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'keys = ur_rg2_teleop.entry:keys',
        ],
    },
)
