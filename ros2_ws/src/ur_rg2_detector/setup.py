from setuptools import find_packages, setup

package_name = 'ur_rg2_detector'

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
    description='The learned ball detector, without ROS: its network, the rendered scenes and '
                'their data sets, training, evaluation and ONNX export.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'train_detector = ur_rg2_detector.train_detector:main',
            'evaluate_detector = ur_rg2_detector.evaluate_detector:main',
        ],
    },
)
