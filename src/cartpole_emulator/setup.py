from glob import glob  # noqa: F401

from setuptools import find_packages, setup

package_name = 'cartpole_emulator'

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
    description="The rig's device emulated: the simulated plant behind the Joint protocol on a pseudo-terminal, in Python or as the firmware on a Cortex-M3 in QEMU.",
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'cartpole_emulator = cartpole_emulator.emulator:main',
        ],
    },
)
