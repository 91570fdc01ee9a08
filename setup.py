# Installs the package's Python module (src/structured_light_stabilizer); used
# by catkin_python_setup(), not to be run by hand.
from setuptools import setup
from catkin_pkg.python_setup import generate_distutils_setup

setup(**generate_distutils_setup(packages=["structured_light_stabilizer"], package_dir={"": "src"}))
