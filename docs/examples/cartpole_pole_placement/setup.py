from setuptools import find_packages, setup

package_name = 'cartpole_pole_placement'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml', 'LICENSE']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='your lab',
    maintainer_email='you@example.invalid',
    description='A pole-placement stabiliser plugin for the cartpole controller manager.',
    license='Apache-2.0',
    entry_points={
        # The group the registry reads; the name left of '=' is the type string
        # (ros2 param set /controller_manager stabilizer pole_placement) and must
        # equal the class's `name`.
        'cartpole_control.stabilizer': [
            'pole_placement = cartpole_pole_placement.pole_placement:PolePlacementStabilizer',
        ],
    },
)
