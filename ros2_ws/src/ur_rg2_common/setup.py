"""Install the ur_rg2_common ament_python package."""

from setuptools import find_packages, setup

package_name = 'ur_rg2_common'

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
    description='What every node of the UR + RG2 graph shares, simulated or real.',
    license='Apache-2.0',
)
