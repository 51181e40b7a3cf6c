from setuptools import find_packages, setup

package_name = 'ur_rg2_hardware'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/launch', ['launch/real_robot.launch.py']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='UR RG2 sim maintainers',
    maintainer_email='maintainers@ur-rg2-sim.invalid',
    description="The real robot's side of the graph: the RG2 adapter between the graph's "
                "GripperCommand contract and OnRobot's ParallelGripperCommand driver.",
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'rg2_adapter = ur_rg2_hardware.entry:rg2_adapter',
        ],
    },
)
