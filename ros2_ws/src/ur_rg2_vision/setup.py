from setuptools import find_packages, setup

package_name = 'ur_rg2_vision'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    # The browser viewer's page; the trained ball detector `vision detector:=learned` runs.
    package_data={package_name: ['web/*', 'models/ball/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='UR RG2 sim maintainers',
    maintainer_email='maintainers@ur-rg2-sim.invalid',
    description='Frame saving and 3D ball detection for the UR + RG2 simulation camera.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'vision = ur_rg2_vision.entry:vision',
            'viewer = ur_rg2_vision.entry:viewer',
            'dataset = ur_rg2_vision.entry:dataset',
        ],
    },
)
