"""sepfm_ros: separable four-point fundamental matrix estimation for ROS 2.

Layers (each calls only downward):

- :mod:`sepfm_ros.geometry` -- ROS-free core (numpy, OpenCV): the paper's two-stage estimator,
  baselines, minimal solvers, epipolar helpers.
- :mod:`sepfm_ros.pipeline` -- images to features to matches to estimate, shared by the node and
  offline processing.
- :mod:`sepfm_ros.stream` -- ROS-free stream logic: pairing, sync, scheduling, health.
- :mod:`sepfm_ros.ros` -- ROS adapters: message conversion, the node, bags.
- :mod:`sepfm_ros.cli` -- the ``sepfm_ros`` console command.
"""

__version__ = "0.1.0"

from sepfm_ros.kernel_cache import ensure_fresh_cache

ensure_fresh_cache()
