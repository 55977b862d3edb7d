"""For colcon only: its ament_python build (colcon-ros 0.5, colcon-core 0.21) runs `setup.py install` and builds
no package from pyproject.toml alone, so this shim is what it runs; setuptools reads every fact from
pyproject.toml, and setup.cfg adds what a ROS 2 workspace needs. colcon reads setup.cfg instead of running this
file to learn what it installs, which it does only while the call below is exactly `setup()`: running it, it
would fail to read back pyproject's requires-python (colcon-python-setup-py 0.2.9 parses repr() of the
distribution, and packaging's SpecifierSet no longer has a literal repr). pip needs neither file: `pip install
-e .` stays the first way in (README)."""

from setuptools import setup

setup()
