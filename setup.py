"""ament_python package circle_collision_ros (works with colcon and with pip)."""
from glob import glob

import numpy
from setuptools import Extension, find_packages, setup

PACKAGE = "circle_collision_ros"

# Console scripts; each is also linked into <prefix>/lib/circle_collision_ros/
# (setup.cfg for colcon, scripts/bootstrap.sh for the venv) so `ros2 run` finds it.
CONSOLE_SCRIPTS = [
    "collision_node = circle_collision_ros.node.collision_node:main",
    "demo_scene = circle_collision_ros.demo.demo_scene:main",
    "demo = circle_collision_ros.demo.run:main",
    "replay = circle_collision_ros.recording.replay:main",
]

# The one-pair entry of time_to_collision (why it is C:
# circle_collision_ros/core/narrow/one_pair.py).
ONE_PAIR = Extension(
    f"{PACKAGE}.core.narrow.one_pair_entry",
    [f"{PACKAGE}/core/narrow/one_pair_entry.c"],
    include_dirs=[numpy.get_include()],
    extra_compile_args=["-O2"],
)

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["tests", "tests.*", "bench", "bench.*"]),
    ext_modules=[ONE_PAIR],
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", sorted(glob("launch/*.launch.py"))),
        (f"share/{PACKAGE}/config", sorted(glob("config/*.yaml") + glob("config/*.xml"))),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="circle_collision_ros maintainers",
    maintainer_email="maintainers@circle-collision-ros.dev",
    description="Predicts when moving circles and spheres will first touch.",
    license="Apache-2.0",
    python_requires=">=3.10",
    entry_points={
        "console_scripts": CONSOLE_SCRIPTS,
        # pytest loads it in every run (cheap: no ROS import until a bag is replayed).
        "pytest11": ["circle_collision_replay = circle_collision_ros.recording.pytest_plugin"],
    },
)
