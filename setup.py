# Installs the Python package rotation_averaging (python/rotation_averaging)
# through catkin_python_setup(); the compiled module _core is built by CMake.
from setuptools import setup
from catkin_pkg.python_setup import generate_distutils_setup

setup(**generate_distutils_setup(packages=["rotation_averaging"], package_dir={"": "python"}))
