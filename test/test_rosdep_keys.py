"""``rosdep install`` on Ubuntu 24.04 (Jazzy's platform): apt where Ubuntu has the package, pip
only where it has none (or one older than setup.py allows), and README's command carries the one
extra step pip keys need under PEP 668.

Static: rosdep is not installed here. The Ubuntu rules of ros/rosdistro's keys and what Ubuntu
24.04 (noble) ships are recorded below, read from rosdistro's rosdep/python.yaml and from Ubuntu's
package pages for noble.
"""

from __future__ import annotations

import ast
import re
import xml.etree.ElementTree as ET
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

# setup.py requirement -> the package.xml key that installs it
KEYS = {
    "numpy": "python3-numpy",
    "opencv-python-headless": "python3-opencv",
    "pillow": "python3-pil",
    "scipy": "python3-scipy",
    "matplotlib": "python3-matplotlib",
    "tqdm": "python3-tqdm",
    "threadpoolctl": "python3-threadpoolctl",
    "numba": "python3-numba-pip",
    "rosbags": "python3-rosbags-pip",
    "rosbags-image": "python3-rosbags-image-pip",
    "distributed": "python3-distributed-pip",
}
# What Ubuntu 24.04 ships for each requirement: (package, version), version None where not
# recorded (rosdistro's key names it for every Ubuntu release), package None where noble has none
# (python3-numba is in jammy and later releases but not in noble).
NOBLE = {
    "numpy": ("python3-numpy", None),
    "opencv-python-headless": ("python3-opencv", None),
    "pillow": ("python3-pil", None),
    "scipy": ("python3-scipy", None),
    "matplotlib": ("python3-matplotlib", None),
    "tqdm": ("python3-tqdm", None),
    "threadpoolctl": ("python3-threadpoolctl", "3.1.0"),
    "numba": (None, None),
    "rosbags": (None, None),
    "rosbags-image": (None, None),
    "distributed": ("python3-distributed", "2023.12.1"),
}
# Ubuntu rules of the keys rosdistro defines (rosdep/python.yaml); a later source, as this
# package's rosdep.yaml is, cannot override them.
ROSDISTRO_UBUNTU = {
    "python3-numpy": ["python3-numpy"],
    "python3-opencv": ["python3-opencv"],
    "python3-pil": ["python3-pil"],
    "python3-scipy": ["python3-scipy"],
    "python3-matplotlib": ["python3-matplotlib"],
    "python3-tqdm": {"*": ["python3-tqdm"]},
    "python3-ruamel.yaml": ["python3-ruamel.yaml"],
    "python3-numba": ["python3-numba"],  # no such package on noble: apt-get fails
    "python3-rosbags-pip": {"pip": {"packages": ["rosbags"]}},
    "python3-pytest": ["python3-pytest"],
    "python3-hypothesis": ["python3-hypothesis"],
    "python3-yaml": ["python3-yaml"],
}


def _setup_requirements() -> dict[str, str]:
    """name -> lower bound of install_requires and the fleet extra of setup.py (all name>=v)."""
    call = next(
        node
        for node in ast.walk(ast.parse((REPO / "setup.py").read_text()))
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "setup"
    )
    kw = {k.arg: k.value for k in call.keywords}
    extras = kw["extras_require"]
    assert isinstance(extras, ast.Dict)
    fleet = next(
        v for k, v in zip(extras.keys, extras.values, strict=True) if ast.literal_eval(k) == "fleet"
    )
    specs = ast.literal_eval(kw["install_requires"]) + ast.literal_eval(fleet)
    return dict(spec.split(">=") for spec in specs)


def _v(version: str) -> tuple[int, ...]:
    return tuple(int(part) for part in version.split("."))


def _exec_keys() -> set[str]:
    root = ET.parse(REPO / "package.xml").getroot()
    return {e.text.strip() for kind in ("depend", "exec_depend") for e in root.findall(kind)}


def _ubuntu_rule(key: str):
    from ruamel.yaml import YAML

    own = dict(YAML(typ="safe").load((REPO / "rosdep.yaml").read_text()))
    if key in ROSDISTRO_UBUNTU:
        return ROSDISTRO_UBUNTU[key]
    assert key in own, f"{key}: defined neither by rosdistro nor by rosdep.yaml"
    return own[key]["ubuntu"]


def _apt_packages(rule) -> list[str] | None:
    """The apt packages an Ubuntu rule installs on noble, or None for a pip rule."""
    if isinstance(rule, dict) and "pip" in rule:
        return None
    if isinstance(rule, dict):
        rule = rule.get("noble", rule.get("*"))
    assert isinstance(rule, list), rule
    return rule


def test_every_requirement_has_its_key_in_package_xml():
    keys = _exec_keys()
    for name in _setup_requirements():
        assert name in KEYS, f"{name}: no rosdep key recorded here"
        assert KEYS[name] in keys, f"{name}: {KEYS[name]} not in package.xml"
        assert name in NOBLE, f"{name}: what Ubuntu 24.04 ships is not recorded"


def test_a_key_uses_ubuntus_package_where_noble_has_one_that_setup_py_allows():
    for name, bound in _setup_requirements().items():
        req = f"{name}>={bound}"
        package, version = NOBLE[name]
        usable = package is not None and (version is None or _v(version) >= _v(bound))
        apt = _apt_packages(_ubuntu_rule(KEYS[name]))
        if usable:
            assert apt == [package], f"{req}: Ubuntu 24.04 has {package}, the key installs {apt}"
        else:
            assert apt is None, f"{req}: noble has no usable package, yet the key installs {apt}"


def test_readme_rosdep_command_carries_the_pep_668_step_when_a_key_is_pip():
    pip_keys = {
        key
        for key in _exec_keys()
        if key.endswith("-pip") and _apt_packages(_ubuntu_rule(key)) is None
    }
    assert pip_keys  # rosbags is on no Ubuntu release
    commands = [
        line for line in (REPO / "README.md").read_text().splitlines() if "rosdep install" in line
    ]
    assert commands, "README has no rosdep install command"
    for line in commands:
        # rosdep (0.25+) refuses pip keys on Python 3.11+ system installs unless pip may
        # break system packages; it passes this variable through sudo
        assert re.search(r"PIP_BREAK_SYSTEM_PACKAGES=1 rosdep install ", line), line
    assert "PIP_BREAK_SYSTEM_PACKAGES" in (REPO / "docs" / "manual.md").read_text()
