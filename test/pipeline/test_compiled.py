"""The warm-up a node runs at start (:func:`sepfm_ros.pipeline.compiled.warm_up`) leaves no
kernel to compile (or load) on a stream's pairs: a kernel compiled mid-stream stalls that pair
for seconds on a fresh install and keeps tens of MB of compiler memory in the node."""

from __future__ import annotations

import json
import subprocess
import sys

# In a fresh process (kernels already loaded in this one would hide a gap): warm up, then
# estimate pairs across inlier ratios with every method and run the pipeline on real pairs,
# and list the kernel signatures that appeared after the warm-up.
PROBE = """
import json, sys
import cv2
from numba.core.registry import CPUDispatcher
from sepfm_ros.pipeline.compiled import warm_up

def signatures():
    found = {}
    for name, module in list(sys.modules.items()):
        if name.startswith("sepfm_ros"):
            for obj in list(vars(module).values()):
                if isinstance(obj, CPUDispatcher):
                    key = obj.py_func.__module__ + "." + obj.py_func.__name__
                    found[key] = sorted(str(s) for s in obj.signatures)
    return found

warm_up()
before = signatures()
from sepfm_ros.geometry import estimate_fundamental
from sepfm_ros.geometry.estimator import METHODS
from sepfm_ros.geometry.synthetic import make_pair
from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig

for inliers, outliers in ((200, 20), (100, 100), (60, 140)):
    pair = make_pair(n_inliers=inliers, n_outliers=outliers, n_lines=2, points_per_line=12,
                     noise=0.5, seed=inliers)
    for method in METHODS:
        estimate_fundamental(pair.pts1, pair.pts2, pair.image_size, method=method, seed=1)
data = sys.argv[1]
pipeline = Pipeline(PipelineConfig())
for a, b in (("kitti_seq2/left/000000.png", "kitti_seq2/right/000000.png"),
             ("templeRing/templeR0001.png", "templeRing/templeR0002.png")):
    images = [cv2.imread(f"{data}/{p}", cv2.IMREAD_GRAYSCALE) for p in (a, b)]
    pipeline.process(*images)
after = signatures()
print(json.dumps({k: v for k, v in after.items() if before.get(k) != v}))
"""


def test_no_kernel_compiles_after_the_warm_up(shared_data):
    r = subprocess.run(
        [sys.executable, "-c", PROBE, str(shared_data)],
        capture_output=True,
        text=True,
        timeout=1200,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    new = json.loads(r.stdout.strip().splitlines()[-1])
    assert new == {}, f"kernels compiled after the warm-up: {sorted(new)}"
