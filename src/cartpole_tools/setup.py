from glob import glob  # noqa: F401

from setuptools import find_packages, setup

package_name = 'cartpole_tools'

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
    maintainer='cartpole maintainers',
    maintainer_email='maintainers@cartpole.invalid',
    description="The engineer's tools over the graph: benchmarks, plant identification and the README's generated reference tables, as `cartpole bench` and `cartpole identify`.",
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
        ],
        'cartpole.commands': [
            'bench = cartpole_tools.commands.bench',
            'identify = cartpole_tools.commands.identify',
            'soak = cartpole_tools.commands.soak',
        ],
    },
)
