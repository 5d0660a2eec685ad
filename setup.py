from glob import glob

from setuptools import find_packages, setup

package_name = 'polyline_mapper'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'benchmarks', 'tools']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools', 'numpy', 'scipy'],
    zip_safe=True,
    maintainer='polyline_mapper maintainers',
    maintainer_email='maintainers@polyline-mapper.dev',
    description='Online 2D polyline maps from laser scans by split-and-merge EM segment fitting.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'polyline-mapper = polyline_mapper.console:main',
            'polyline_mapper_node = polyline_mapper.console:node_main',
        ],
    },
)
