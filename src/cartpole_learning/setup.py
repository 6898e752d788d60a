from setuptools import find_packages, setup

package_name = 'cartpole_learning'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    package_data={package_name: ['policies/*.npz']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml', 'LICENSE']),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='cartpole maintainers',
    maintainer_email='maintainers@cartpole.invalid',
    description='Learned control on the same plant: the gymnasium environment of the rig, '
                '`cartpole train` (PPO) and the `policy` controller plugin with a shipped policy.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
        ],
        'cartpole.commands': [
            'train = cartpole_learning.commands.train',
        ],
        'cartpole_control.swingup': [
            'policy = cartpole_learning.plugin:PolicySwingUp',
        ],
        'cartpole_control.stabilizer': [
            'policy = cartpole_learning.plugin:PolicyStabilizer',
        ],
    },
)
