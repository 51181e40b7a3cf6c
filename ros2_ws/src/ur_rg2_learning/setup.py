from setuptools import find_packages, setup

package_name = 'ur_rg2_learning'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    # The trained Reach and Pick policies the policy node runs.
    package_data={package_name: ['policies/reach/*', 'policies/pick/*', 'policies/pick_cloned/*',
                                 'policies/pick_demos/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='UR RG2 sim maintainers',
    maintainer_email='maintainers@ur-rg2-sim.invalid',
    description='Gymnasium environments on the UR + RG2 sim world, a DDPG baseline and the '
                'policy node that runs a trained policy in the live graph.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'train_policy = ur_rg2_learning.train:main',
            'evaluate_policy = ur_rg2_learning.evaluate:main',
            'policy = ur_rg2_learning.entry:policy',
        ],
    },
)
