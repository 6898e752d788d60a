from glob import glob

from setuptools import find_packages, setup

package_name = 'cartpole_bringup'

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
    description='The `cartpole` command: starts the node graph, records bags, analyses runs, benchmarks.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'cartpole = cartpole_bringup.cli:main',
            'cartpole_recorder = cartpole_bringup.graph.recorder:main',
        ],
    },
)
