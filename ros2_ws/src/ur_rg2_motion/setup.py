from setuptools import find_packages, setup

package_name = 'ur_rg2_motion'

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
    description='Cartesian control of the UR + RG2 (closed-form UR kinematics) and the '
                'vision-guided ball pick.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'motion = ur_rg2_motion.entry:motion',
        ],
    },
)
