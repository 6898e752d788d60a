from glob import glob

from setuptools import find_packages, setup

package_name = 'cartpole_hw'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml', 'LICENSE']),
        ('share/' + package_name + '/config', glob('config/*')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='cartpole maintainers',
    maintainer_email='maintainers@cartpole.invalid',
    description='Serial bridge to the Arduino Due rig (Joint protocol), device emulator and firmware support.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'hw_bridge = cartpole_hw.hw_node:main',
        ],
    },
)
