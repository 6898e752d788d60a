from glob import glob

from setuptools import find_packages, setup

package_name = 'cartpole_control'

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
    description='Controller manager with swing-up and stabiliser plugins, catch trigger and friction feedforward.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'controller_manager = cartpole_control.manager_node:main',
        ],
        # Controller plugins: the entry-point name is the type string users
        # choose with `ros2 param set /controller_manager swingup <name>`.
        'cartpole_control.swingup': [
            'full_energy = cartpole_control.controllers.full_energy:FullEnergySwingUp',
            'pendulum_energy = cartpole_control.controllers.pendulum_energy:PendulumEnergySwingUp',
            'sign_based = cartpole_control.controllers.sign_based:SignBasedSwingUp',
            'energy_saturated = cartpole_control.controllers.energy_saturated:EnergySaturatedSwingUp',
            'time_optimal = cartpole_control.controllers.time_optimal:TimeOptimalSwingUp',
        ],
        'cartpole_control.stabilizer': [
            'lqg = cartpole_control.controllers.lqg:LqgStabilizer',
            'pid = cartpole_control.controllers.pid:PidStabilizer',
            'smc = cartpole_control.controllers.smc:SlidingModeStabilizer',
            'mpc = cartpole_control.controllers.mpc:MpcStabilizer',
        ],
    },
)
