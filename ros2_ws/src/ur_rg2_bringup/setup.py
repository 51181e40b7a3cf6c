from glob import glob

from setuptools import find_packages, setup

package_name = 'ur_rg2_bringup'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/config/examples', glob('config/examples/*.yaml')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='UR RG2 sim maintainers',
    maintainer_email='maintainers@ur-rg2-sim.invalid',
    description='The UR + RG2 node graph: its launch file, and the graph with keys in a terminal.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'graph = ur_rg2_bringup.run:main',
        ],
    },
)
