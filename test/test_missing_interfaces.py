"""A command started where sepfm_msgs is not importable says so in one line that names the fix.

This virtual environment has sepfm_msgs pip-installed (README's install line). To start a command
as on a machine without it, ``without_pip_sepfm_msgs`` gives an environment whose interpreter
does not look for sepfm_msgs in this environment's site-packages (a ``sitecustomize`` that
narrows the path finder for that one package), while every other package, and a sepfm_msgs on
PYTHONPATH (a colcon install), is found as usual. test_colcon_run.py starts the colcon-built node
in it after a plain ``colcon build``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

_SITECUSTOMIZE = """\
import sys
from importlib.machinery import PathFinder

_HIDDEN_FROM = {hidden!r}


class _WithoutPipSepfmMsgs(PathFinder):
    @classmethod
    def find_spec(cls, name, path=None, target=None):
        if name.split(".")[0] == "sepfm_msgs" and path is None:
            path = [p for p in sys.path if p.rstrip("/") not in _HIDDEN_FROM]
        return PathFinder.find_spec(name, path, target)


sys.meta_path[:] = [_WithoutPipSepfmMsgs if f is PathFinder else f for f in sys.meta_path]
"""


def without_pip_sepfm_msgs(folder: Path, env: dict[str, str] | None = None) -> dict[str, str]:
    """``env`` (default: this one) whose Python finds no sepfm_msgs in site-packages."""
    site = {sysconfig.get_path(kind) for kind in ("purelib", "platlib")}
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "sitecustomize.py").write_text(
        _SITECUSTOMIZE.format(hidden=sorted(p.rstrip("/") for p in site))
    )
    env = dict(os.environ if env is None else env)
    env["PYTHONPATH"] = os.pathsep.join([str(folder), *filter(None, [env.get("PYTHONPATH")])])
    return env


def test_the_hiding_environment_hides_only_the_pip_installed_sepfm_msgs(tmp_path):
    env = without_pip_sepfm_msgs(tmp_path / "hide")
    code = "import importlib.util as u; print(u.find_spec('sepfm_msgs'), u.find_spec('numpy'))"
    r = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("None ModuleSpec(name='numpy'"), r.stdout
    # a sepfm_msgs on PYTHONPATH (as a sourced colcon install puts it) is still found
    (tmp_path / "built" / "sepfm_msgs").mkdir(parents=True)
    (tmp_path / "built" / "sepfm_msgs" / "__init__.py").write_text("")
    env["PYTHONPATH"] += os.pathsep + str(tmp_path / "built")
    r = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True
    )
    assert str(tmp_path / "built" / "sepfm_msgs") in r.stdout, r.stdout + r.stderr


@pytest.mark.parametrize("where", ["elsewhere", "clone"])
def test_pip_install_without_sepfm_msgs_names_pip_install_in_one_line(tmp_path, where):
    # `sepfm_ros node` from this editable install, on a machine where sepfm_msgs is not installed;
    # started in the clone, Python finds the folder sepfm_msgs/ there (a namespace package)
    env = without_pip_sepfm_msgs(tmp_path / "hide")
    env.pop("AMENT_PREFIX_PATH", None)
    r = subprocess.run(
        [sys.executable, "-m", "sepfm_ros", "node"],
        env=env,
        cwd=REPO if where == "clone" else tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    output = r.stdout + r.stderr
    assert r.returncode == 1, output
    assert "Traceback" not in output, output
    assert output.strip().count("\n") == 0, output
    assert output.startswith("sepfm_ros: the interface package sepfm_msgs is not built"), output
    assert f"run `pip install {REPO / 'sepfm_msgs'}`" in output, output
