#!/usr/bin/env bash
# CI step: the oldest dependency versions setup.py allows (what Ubuntu 24.04 ships for ROS 2 Jazzy),
# in a second virtual environment, running the geometry tests and the node tests that exercise the
# estimator end to end. Prints how long the install and the tests took.
set -euo pipefail
cd "$(dirname "$0")/.."
# outside the repository, so that lint, colcon and pytest never look into it
venv=$(mktemp -d)/venv-oldest
trap 'rm -rf "$(dirname "$venv")"' EXIT
# its own kernel cache: numba caches beside the sources, and two numba versions would each
# invalidate the other's kernels for the main test run
export NUMBA_CACHE_DIR="$(dirname "$venv")/numba-cache"
start=$(date +%s)
python3 -m venv "$venv"
"$venv/bin/python" -m pip install -q --upgrade pip
# The lower bounds of setup.py's install_requires, pinned (test_package.py checks that the pins
# are those bounds); the install fails if setup.py's bounds moved above them. The node tests
# import sepfm_msgs: built here as in README (the pins constrain what it runs with, not its
# isolated build environment).
"$venv/bin/python" -m pip install -q -c .ci/oldest-constraints.txt ./sepfm_msgs -e '.[ros]' \
    pytest hypothesis
"$venv/bin/python" -m pip check
"$venv/bin/python" - <<'PY'
import importlib.metadata as md
pins = dict(
    line.split("==") for line in open(".ci/oldest-constraints.txt")
    if "==" in line and not line.startswith("#")
)
for name, want in sorted(pins.items()):
    have = md.version(name.strip())
    assert have == want.strip(), f"{name}: installed {have}, expected {want.strip()}"
    print(f"  {name}=={have}")
PY
installed=$(date +%s)
echo "oldest versions installed in $((installed - start)) s"
"$venv/bin/python" -m pytest -q -p no:cacheprovider \
    test/geometry/test_geometry_solvers.py test/geometry/test_geometry_estimator.py \
    test/geometry/test_geometry_real.py \
    test/ros/test_image_conversion.py test/pipeline/test_pipeline.py test/pipeline/test_features.py \
    test/ros/test_node_startup.py test/ros/test_node_live.py
echo "oldest versions: tests took $(($(date +%s) - installed)) s"
