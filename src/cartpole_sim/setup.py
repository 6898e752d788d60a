from glob import glob

from setuptools import find_packages, setup

package_name = 'cartpole_sim'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml', 'LICENSE']),
        ('share/' + package_name + '/config', glob('config/*')),
        ('share/' + package_name + '/urdf', ['urdf/cartpole.urdf']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='cartpole maintainers',
    maintainer_email='maintainers@cartpole.invalid',
    description='Plant model of the thesiss cart-pendulum (dynamics, friction, actuator, end stops, encoders) and the simulator node.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'sim_node = cartpole_sim.sim_node:main',
        ],
    },
)
