"""SupeRANSAC (the optional ``pysuperansac``) through the evaluation's method table: both entries
on a shared pair with a sane F, its threshold mapped to the same pixels as every method's, and the
gate when the package is missing (as PoseLib's: left out of ``all``, a named request is an error
that says what to install).

``pysuperansac`` ships a CPython 3.11 wheel only: where it is missing the tests that run it skip
(fail under CI / SEPFM_REQUIRE_SHARED=1, where ``.ci/run`` installs the ``test`` extra).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest
from optional_tools import missing_tool

from sepfm_ros.evaluation.manifest import load_manifest
from sepfm_ros.evaluation.matches_cache import MatchesCache, MatchSettings
from sepfm_ros.evaluation.methods import (
    SUPERANSAC_ADAPTIVE_MIN_ITERATIONS,
    available_methods,
    resolve_methods,
    superansac_available,
)
from sepfm_ros.evaluation.metrics import positives, run_metrics

PAIR = "templeRing/templeR0032~templeR0046"
INSTALL = "pip install 'sepfm_ros[superansac]' (Python 3.11 only)"


def _require_superansac() -> None:
    if not superansac_available():
        missing_tool("pysuperansac", INSTALL)


def _sampson(F: np.ndarray, pts_a: np.ndarray, pts_b: np.ndarray) -> np.ndarray:
    """(N,) Sampson distance in px of each match under F (x_b^T F x_a = 0)."""
    xa = np.c_[pts_a, np.ones(len(pts_a))]
    xb = np.c_[pts_b, np.ones(len(pts_b))]
    Fxa, Ftxb = xa @ F.T, xb @ F
    num = np.abs(np.sum(xb * Fxa, axis=1))
    return num / np.sqrt(Fxa[:, 0] ** 2 + Fxa[:, 1] ** 2 + Ftxb[:, 0] ** 2 + Ftxb[:, 1] ** 2)


@pytest.fixture(scope="module")
def temple_pair(shared_data, tmp_path_factory):
    pairs, _ = load_manifest(shared_data / "pairs.json")
    pair = next(p for p in pairs if p.pair_id == PAIR)
    cache = MatchesCache(tmp_path_factory.mktemp("matches"), MatchSettings("sift", 0.75))
    return pair, cache.matches(pair)


def test_both_entries_give_a_sane_F_on_a_shared_pair(temple_pair):
    _require_superansac()
    pair, m = temple_pair
    pos = positives(pair.F_gt, m.pts_a, m.pts_b)
    threshold = 1.0
    default, adaptive = resolve_methods("superansac,superansac-adaptive")
    assert (default.family, adaptive.family) == ("superansac", "superansac")
    for method in (default, adaptive, default):  # twice the same: nothing kept between calls
        r = method.run(m.pts_a, m.pts_b, m.size_a, m.size_b, threshold, 0.99, 0)
        assert r.F is not None and r.status == "ok", method.name
        assert math.isclose(float(np.linalg.norm(r.F)), 1.0)
        met = run_metrics(r.F, m.pts_a, m.pts_b, pos, threshold)
        assert met.succeeded and met.f_score > 0.9 and met.median_error < 0.5, method.name
        assert r.ms > 0 and r.hypotheses is not None
        if method is default:  # its default min_iterations, 1000
            assert r.hypotheses >= 1000
        else:  # its adaptive stop on an easy pair, below the default's floor
            assert SUPERANSAC_ADAPTIVE_MIN_ITERATIONS <= r.hypotheses < 1000
        # its own inliers are the matches within threshold / sqrt(2) px Sampson distance: the
        # symmetric epipolar distance (the evaluation's threshold) of a match whose two
        # point-line distances are equal
        within = int(np.count_nonzero(_sampson(r.F, m.pts_a, m.pts_b) < threshold / math.sqrt(2)))
        assert abs(r.own_inliers - within) <= 0.02 * within, (r.own_inliers, within)


_HIDE = """
import sys
from importlib.machinery import PathFinder

class Hide(PathFinder):
    @classmethod
    def find_spec(cls, name, path=None, target=None):
        if name.split(".")[0] == "pysuperansac":
            return None
        return PathFinder.find_spec(name, path, target)

sys.meta_path[:] = [Hide if f is PathFinder else f for f in sys.meta_path]
"""


def test_without_the_package_the_methods_are_left_out_and_asking_says_what_to_install(tmp_path):
    code = _HIDE + (
        "from sepfm_ros.evaluation.methods import available_methods, resolve_methods\n"
        "names = [m.name for m in resolve_methods('all')]\n"
        "assert names == available_methods(), names\n"
        "assert not [n for n in names if n.startswith('superansac')], names\n"
        "assert 'sep4' in names and 'cv-magsac' in names\n"
        "for spec in ('superansac', 'sep4,superansac-adaptive'):\n"
        "    try:\n"
        "        resolve_methods(spec)\n"
        "    except ValueError as e:\n"
        "        print(e)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.strip().splitlines()
    assert len(lines) == 2
    assert lines[0].startswith("method 'superansac' needs SupeRANSAC")
    assert lines[1].startswith("method 'superansac-adaptive' needs SupeRANSAC")
    assert all("pip install 'sepfm_ros[superansac]'" in line for line in lines)
    # and the eval command turns it into a usage error naming the fix
    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps([]))
    cmd = ("import sys; from sepfm_ros.evaluation import cli; "
           "sys.exit(cli.main(['--manifest', sys.argv[1], '--methods', 'superansac']))"
           )  # fmt: skip
    r = subprocess.run([sys.executable, "-c", _HIDE + cmd, str(manifest)], capture_output=True,
                       text=True, cwd=tmp_path)  # fmt: skip
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert "pip install 'sepfm_ros[superansac]'" in r.stderr


def test_installed_package_is_in_all():
    _require_superansac()
    names = [m.name for m in resolve_methods("all")]
    assert names[-2:] == ["superansac", "superansac-adaptive"] == available_methods()[-2:]
