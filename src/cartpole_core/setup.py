from glob import glob  # noqa: F401

from setuptools import find_packages, setup

package_name = 'cartpole_core'

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
    description="What every layer shares: the thesis's plant model (parameters, dynamics, energies, linearisation) and the node plumbing (node runner, real-time settings, diagnostics, domain guard, DDS profile).",
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
        ],
    },
)
