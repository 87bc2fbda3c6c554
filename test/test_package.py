"""Package-level checks: lint and format (ruff), the console command, the ROS-free core."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from optional_tools import missing_tool

REPO_ROOT = Path(__file__).resolve().parent.parent


def _ruff() -> list[str]:
    exe = shutil.which("ruff") or str(Path(sys.executable).with_name("ruff"))
    if not Path(exe).exists():
        missing_tool("ruff", "pip install ruff==0.17.6, or pip install -e '.[test]'")
    return [exe]


def test_ruff_lint_passes():
    r = subprocess.run([*_ruff(), "check", "."], cwd=REPO_ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_ruff_format_is_clean():
    r = subprocess.run(
        [*_ruff(), "format", "--check", "."], cwd=REPO_ROOT, capture_output=True, text=True
    )
    assert r.returncode == 0, r.stdout + r.stderr


def test_console_command_lists_every_subcommand():
    r = subprocess.run(
        [sys.executable, "-m", "sepfm_ros", "--help"], capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 0
    for name in (
        "node",
        "make_bag",
        "replay",
        "record",
        "process",
        "eval",
        "demo",
        "warm_up",
        "rectify",
    ):
        assert f"  {name}" in r.stdout
    r = subprocess.run(
        [sys.executable, "-m", "sepfm_ros", "no_such_command"], capture_output=True, text=True
    )
    assert r.returncode == 2 and "unknown command" in r.stderr


@pytest.mark.parametrize(
    "name", ["node", "make_bag", "replay", "record", "process", "eval", "warm_up", "rectify"]
)
def test_every_subcommand_has_help(name):
    r = subprocess.run(
        [sys.executable, "-m", "sepfm_ros", name, "--help"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert "usage" in r.stdout.lower()


def test_geometry_core_imports_no_ros():
    code = (
        "import sys, sepfm_ros.geometry, sepfm_ros.pipeline.features;"
        "bad = [m for m in sys.modules if m.split('.')[0] in "
        "('rclpy', 'sensor_msgs', 'std_msgs', 'diagnostic_msgs', 'rosbags')];"
        "print(bad); sys.exit(1 if bad else 0)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


# ------------------------------------------------------------------ package.xml and rosdep
# Core packages of ROS 2 Jazzy (ros/rosdistro jazzy/distribution.yaml: repositories rclpy,
# rcl_interfaces, common_interfaces, ament_index, launch, launch_ros): rosdep resolves them
# as ros-jazzy-* packages.
JAZZY_PACKAGES = {
    "rclpy",
    "builtin_interfaces",
    "rcl_interfaces",
    "lifecycle_msgs",
    "rosgraph_msgs",
    "sensor_msgs",
    "std_msgs",
    "diagnostic_msgs",
    "geometry_msgs",
    "ament_index_python",
    "launch",
    "launch_ros",
}
# Packages of this repository's workspace (``rosdep install --from-paths`` names their folders,
# README): rosdep resolves them from the workspace, not from rosdistro.
WORKSPACE_PACKAGES = {"sepfm_msgs": REPO_ROOT / "sepfm_msgs"}
# Core Jazzy packages (ros2/ament_cmake, ros2/rosidl_defaults) that build an interface package.
JAZZY_INTERFACE_BUILD = {"ament_cmake", "rosidl_default_generators", "rosidl_default_runtime"}
# Keys of ros/rosdistro rosdep/python.yaml, each read there with an Ubuntu rule that covers
# Jazzy's 24.04 (a plain package list, no per-release list that leaves it out).
ROSDISTRO_KEYS = {
    "python3-numpy",
    "python3-opencv",
    "python3-pil",
    "python3-scipy",
    "python3-matplotlib",
    "python3-tqdm",
    "python3-ruamel.yaml",
    "python3-pytest",
    "python3-hypothesis",
    "python3-yaml",
}
# Keys rosdistro has whose Ubuntu rule lists only older releases: unresolvable on Jazzy.
ROSDISTRO_KEYS_NOT_ON_NOBLE = {"python3-numba"}
# Third-party top-level modules imported by the package, its launch file and its tests, and the
# rosdep key that installs each (llvmlite is numba's code generator and comes with it).
MODULE_KEYS = {
    "numpy": "python3-numpy",
    "cv2": "python3-opencv",
    "PIL": "python3-pil",
    "scipy": "python3-scipy",
    "matplotlib": "python3-matplotlib",
    "tqdm": "python3-tqdm",
    "ruamel": "python3-ruamel.yaml",
    "rosbags": "python3-rosbags-pip",
    "rosbags.image": "python3-rosbags-image-pip",
    "numba": "python3-numba-pip",
    "llvmlite": "python3-numba-pip",
    "threadpoolctl": "python3-threadpoolctl",
    "distributed": "python3-distributed-pip",
    "dask": "python3-distributed-pip",
    "pytest": "python3-pytest",
    "hypothesis": "python3-hypothesis",
    "yaml": "python3-yaml",
    **{name: name for name in JAZZY_PACKAGES | set(WORKSPACE_PACKAGES)},
}
# Imported only where present; the code and tests say so when it is missing.
OPTIONAL_MODULES = {"poselib", "pysuperansac"}


def _package_xml(folder: Path = REPO_ROOT) -> dict[str, set[str]]:
    """Dependency kind -> keys of ``folder/package.xml``; also its "name", "format",
    "build_type" and "member_of_group"."""
    import xml.etree.ElementTree as ET

    root = ET.parse(folder / "package.xml").getroot()
    kinds = ("depend", "exec_depend", "test_depend", "build_depend", "build_export_depend")
    kinds += ("buildtool_depend", "name", "member_of_group", "export/build_type")
    found = {kind: {e.text.strip() for e in root.findall(kind)} for kind in kinds}
    found["format"] = {root.get("format", "")}
    return found


def _dependency_keys(folder: Path = REPO_ROOT) -> set[str]:
    deps = _package_xml(folder)
    kinds = ("depend", "exec_depend", "test_depend", "build_depend", "build_export_depend")
    return set().union(*(deps[kind] | deps["buildtool_depend"] for kind in kinds))


def _rosdep_yaml() -> dict:
    from ruamel.yaml import YAML

    return dict(YAML(typ="safe").load((REPO_ROOT / "rosdep.yaml").read_text()))


def _imported_modules(paths: list[Path], local: set[str]) -> set[str]:
    """Third-party modules imported anywhere in ``paths`` ("rosbags.image" kept apart)."""
    import ast

    found = set()
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            for name in names:
                top = name.split(".")[0]
                if top in sys.stdlib_module_names or top in local:
                    continue
                found.add("rosbags.image" if name.startswith("rosbags.image") else top)
    return found


def test_every_package_xml_key_resolves_on_jazzy():
    own = set(_rosdep_yaml())
    used = _dependency_keys()
    unknown = used - JAZZY_PACKAGES - ROSDISTRO_KEYS - own - set(WORKSPACE_PACKAGES)
    assert not unknown, f"keys neither Jazzy packages nor verified rosdep keys: {unknown}"
    assert not used & ROSDISTRO_KEYS_NOT_ON_NOBLE
    for key, folder in WORKSPACE_PACKAGES.items():
        assert _package_xml(folder)["name"] == {key}, f"{folder}/package.xml is not {key}"


def test_interface_package_is_a_rosidl_package_of_jazzy_keys():
    folder = WORKSPACE_PACKAGES["sepfm_msgs"]
    xml = _package_xml(folder)
    assert xml["format"] == {"3"}
    assert xml["export/build_type"] == {"ament_cmake"}
    assert xml["member_of_group"] == {"rosidl_interface_packages"}
    assert {"ament_cmake", "rosidl_default_generators"} <= xml["buildtool_depend"]
    unknown = _dependency_keys(folder) - JAZZY_PACKAGES - JAZZY_INTERFACE_BUILD
    assert not unknown, f"sepfm_msgs keys that are no core Jazzy packages: {unknown}"


def _requirement_name(spec: str) -> str:
    return spec.split("[")[0].split("=")[0].split(">")[0].split("<")[0].strip()


def test_interface_package_builds_from_jazzy_wheels_only():
    import ast

    tomllib = pytest.importorskip("tomllib", reason="reads pyproject.toml with Python 3.11+")

    pyproject = tomllib.loads((WORKSPACE_PACKAGES["sepfm_msgs"] / "pyproject.toml").read_text())
    build = pyproject["build-system"]["requires"]
    runtime = pyproject["project"]["dependencies"]
    for spec in build + runtime:
        name = _requirement_name(spec)
        if name.startswith("ros-"):  # never a non-Jazzy ros-* wheel, and pinned to one release
            assert name.startswith("ros-jazzy-") and "==" in spec, spec
    # setup.py's test extra gives colcon the same build packages (test_colcon_run)
    tree = ast.parse((REPO_ROOT / "setup.py").read_text())
    in_setup = next(
        ast.literal_eval(node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "SEPFM_MSGS_BUILD"
    )
    assert set(in_setup) == {s for s in build if s.startswith("ros-jazzy-")}


def test_rosdep_yaml_defines_only_missing_keys_for_ubuntu_and_debian():
    rules = _rosdep_yaml()
    used = _dependency_keys()
    for key, rule in rules.items():
        assert key in used, f"{key} is defined in rosdep.yaml but not used in package.xml"
        assert key not in ROSDISTRO_KEYS | ROSDISTRO_KEYS_NOT_ON_NOBLE | JAZZY_PACKAGES, key
        assert {"ubuntu", "debian"} <= set(rule), f"{key} lacks an ubuntu or debian rule"
        if key.endswith("-pip"):
            assert rule["ubuntu"]["pip"]["packages"], key


def test_every_imported_module_is_declared_in_package_xml():
    deps = _package_xml()
    exec_keys = deps["depend"] | deps["exec_depend"]
    test_keys = exec_keys | deps["test_depend"]
    runtime = _imported_modules(
        sorted((REPO_ROOT / "sepfm_ros").rglob("*.py")) + sorted(REPO_ROOT.glob("launch/*.py")),
        {"sepfm_ros"},
    )
    test_files = sorted((REPO_ROOT / "test").rglob("*.py"))
    benchmarks = sorted((REPO_ROOT / "benchmarks").glob("*.py"))  # tests import bench_docs
    local = {"sepfm_ros"} | {p.stem for p in test_files + benchmarks}
    tests = _imported_modules(test_files, local)
    for modules, keys, what in ((runtime, exec_keys, "exec_depend"), (tests, test_keys, "test")):
        unmapped = modules - set(MODULE_KEYS) - OPTIONAL_MODULES
        assert not unmapped, f"imports without a known rosdep key: {unmapped}"
        missing = {MODULE_KEYS[m] for m in modules - OPTIONAL_MODULES} - keys
        assert not missing, f"imported but not declared as {what} in package.xml: {missing}"


def _install_requires() -> dict[str, str]:
    """name -> lower bound of every ``name>=version`` in setup.py's install_requires."""
    import ast

    tree = ast.parse((REPO_ROOT / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.keyword) and node.arg == "install_requires":
            specs = [ast.literal_eval(e) for e in node.value.elts]
            return dict(s.split(">=") for s in specs)
    raise AssertionError("setup.py has no install_requires")


def test_oldest_ci_pins_are_setup_py_lower_bounds():
    # .ci/oldest.sh installs these pins and runs the geometry, image and node tests on them: the
    # pins must be the oldest releases setup.py allows, so the bounds are what CI has tested
    lines = (REPO_ROOT / ".ci" / "oldest-constraints.txt").read_text().splitlines()
    pins = dict(line.split("==") for line in lines if line and not line.startswith("#"))
    bounds = _install_requires()
    for name, bound in bounds.items():
        assert name in pins, f"{name} has no pin in .ci/oldest-constraints.txt"
        want = [int(x) for x in bound.split(".")]
        have = [int(x) for x in pins[name].split(".")]
        assert have[: len(want)] == want, f"{name}: setup.py >={bound}, CI tests {pins[name]}"
