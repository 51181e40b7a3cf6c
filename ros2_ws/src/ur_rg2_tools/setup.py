from setuptools import find_packages, setup

package_name = 'ur_rg2_tools'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    # The 3D view's page and the three.js / urdf-loader modules it runs (web/vendor/PROVENANCE.md).
    package_data={package_name: ['web/**/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='UR RG2 sim maintainers',
    maintainer_email='maintainers@ur-rg2-sim.invalid',
    description='Recording and replaying the graph as MCAP, and a 3D view of the scene in the '
                'browser.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'record = ur_rg2_tools.entry:record',
            'replay = ur_rg2_tools.entry:replay',
            'recover = ur_rg2_tools.entry:recover',
            'info = ur_rg2_tools.entry:info',
            'to_lerobot = ur_rg2_tools.entry:to_lerobot',
            'demos = ur_rg2_tools.entry:demos',
            'view3d = ur_rg2_tools.entry:view3d',
        ],
    },
)
