"""The compiled line-pair search and stage 1 against plain reference implementations: the
point-set Hough kernel vs cv2.HoughLinesPointSet, Hough lines from points vs cv2.HoughLines on
the binary image, the joint accumulator and ranking vs a
dense I1^T I2, the scalar H_e kernels vs the batched numpy solvers, stage-1 RANSAC on exact data."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sepfm_ros.geometry.robust.contract import Problem
from sepfm_ros.geometry.robust.loop import run_ransac
from sepfm_ros.geometry.robust.trials import trials_needed
from sepfm_ros.geometry.separable.line_pairs import (
    LineSearchOptions,
    control_points,
    hough_lines,
    hough_point_set,
    incidence,
    rank_line_pairs,
    working_scale,
)
from sepfm_ros.geometry.separable.stage1 import (
    line_homography_error,
    stage1_ransac,
    transfer_errors,
)
from sepfm_ros.geometry.solvers.line_homography import (
    line_homography_3pt,
    line_homography_3pt_kernel,
    line_homography_lsq,
    line_homography_lsq_kernel,
    transfer,
)


def _points_with_lines(rng: np.random.Generator, size=(1024, 768), n_lines=4, n_rand=200):
    w, h = size
    pts = [np.c_[rng.uniform(0, w, n_rand), rng.uniform(0, h, n_rand)]]
    for _ in range(n_lines):
        a, b = rng.uniform([0, 0], [w, h], size=(2, 2))
        t = rng.uniform(0, 1, 12)[:, None]
        pts.append(a + t * (b - a))
    return np.concatenate(pts)


def _hough_on_image(pts, size, opts):
    """The reference: cv2.HoughLines on the binary image of the points (the paper's B_1)."""
    s = working_scale(size, opts.width)
    w, h = int(np.ceil(size[0] * s)), int(np.ceil(size[1] * s))
    img = np.zeros((h, w), np.uint8)
    q = np.rint(pts * s).astype(int)
    ok = (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
    img[q[ok, 1], q[ok, 0]] = 255
    found = cv2.HoughLines(img, 1.0, np.pi / 180.0, opts.min_votes)
    if found is None:
        return np.zeros((0, 2))
    return found[:, 0].astype(np.float64)  # (rho, theta) at the working resolution


@pytest.mark.parametrize("seed", range(4))
def test_hough_from_points_matches_hough_on_binary_image(seed):
    rng = np.random.default_rng(seed)
    size = (1024, 768)
    pts = _points_with_lines(rng, size)
    opts = LineSearchOptions(max_lines=10_000)
    ours = hough_lines(pts, size, opts)
    ref = _hough_on_image(pts, size, opts)
    s = working_scale(size, opts.width)
    assert len(ours) > 4
    # same set of (rho, theta) cells; ties in the vote count may come in another order
    theta = np.arctan2(ours[:, 1], ours[:, 0])
    cells = {(round(-c * s), round(np.degrees(t))) for c, t in zip(ours[:, 2], theta, strict=True)}
    ref_cells = {(round(r), round(np.degrees(t))) for r, t in ref}
    assert len(cells ^ ref_cells) <= 0.02 * len(ref_cells)
    # unit normals, strongest first: the first line carries at least as many points as any other
    assert np.allclose(np.hypot(ours[:, 0], ours[:, 1]), 1.0)
    inc = incidence(pts, ours, size, opts)
    assert inc[:, 0].sum() >= 12


@pytest.mark.parametrize("kind", ["uniform pixels", "pixels on lines", "sub-pixel points"])
def test_point_set_hough_equals_opencv_line_for_line(kind):
    # hough_point_set is cv2.HoughLinesPointSet's arithmetic computed sparsely: same lines,
    # votes, rho, theta and order, on integer pixels (what hough_lines passes) and others
    rng = np.random.default_rng({"uniform pixels": 0, "pixels on lines": 1}.get(kind, 2))
    compared = lines = 0
    for _ in range(60):
        w, h = (int(v) for v in rng.integers(60, 800, 2))
        m = int(rng.integers(5, 400))
        if kind == "uniform pixels":
            pts = np.c_[rng.integers(0, w, m), rng.integers(0, h, m)]
        elif kind == "pixels on lines":
            a, b = rng.uniform([0, 0], [w - 1, h - 1], (2, 5, 2))
            t = rng.uniform(0, 1, (5, m // 5 + 1, 1))
            pts = np.rint(a[:, None] + t * (b - a)[:, None]).reshape(-1, 2)
        else:
            pts = np.c_[rng.uniform(0, w, m), rng.uniform(0, h, m)]
        pts = np.unique(pts.astype(np.float32), axis=0)
        args = (
            int(rng.integers(1, 120)), int(rng.integers(1, 8)), float(-w),
            float(np.ceil(np.hypot(w, h))), 1.0, 0.0, np.pi, np.pi / 180.0,
        )  # fmt: skip
        ref = cv2.HoughLinesPointSet(pts.reshape(-1, 1, 2), *args)
        ref = np.zeros((0, 3)) if ref is None else ref.reshape(-1, 3)
        ours = hough_point_set(pts, *args)
        assert ours.shape == ref.shape
        assert np.array_equal(ours, ref)
        compared += 1
        lines += len(ref)
    assert compared == 60 and lines > 200  # the comparison saw many lines


def _rank_reference(I1, I2, min_votes, max_pairs):
    """Greedy ranking on the dense accumulator A = I1^T I2."""
    A = (I1.astype(int).T @ I2.astype(int)).ravel()
    cand = np.flatnonzero(A >= min_votes)
    cand = cand[np.argsort(-A[cand], kind="stable")][: 20 * max_pairs]
    used = np.zeros(len(I1), bool)
    out = []
    for c in cand:
        i, j = divmod(int(c), I2.shape[1])
        sup = I1[:, i] & I2[:, j]
        if np.count_nonzero(used[sup]) * 2 > sup.sum():
            continue
        out.append((i, j, np.flatnonzero(sup)))
        used |= sup
        if len(out) >= max_pairs:
            break
    return out


@pytest.mark.parametrize("seed", range(6))
def test_rank_line_pairs_matches_dense_accumulator(seed):
    rng = np.random.default_rng(seed)
    n, k1, k2 = 300, 40, 50
    I1 = rng.random((n, k1)) < 0.08
    I2 = rng.random((n, k2)) < 0.08
    for min_votes, max_pairs in ((2, 6), (3, 3), (4, 10)):
        lines, supports = rank_line_pairs(I1, I2, min_votes, max_pairs)
        ref = _rank_reference(I1, I2, min_votes, max_pairs)
        assert len(lines) == len(ref) > 0
        for (i, j), sup, (ri, rj, rsup) in zip(lines, supports, ref, strict=True):
            assert (i, j) == (ri, rj)
            assert np.array_equal(np.flatnonzero(sup), rsup)


@pytest.mark.parametrize("seed", range(4))
def test_rank_line_pairs_ties_at_the_candidate_cut_match_dense_accumulator(seed):
    """Lines through the same few points: most candidates overlap and are skipped, so the ranking
    reads down to the 20 * max_pairs cut, where many pairs tie on their count."""
    rng = np.random.default_rng(seed)
    n, k1, k2 = 200, 60, 60
    I1 = np.zeros((n, k1), bool)
    I2 = np.zeros((n, k2), bool)
    I1[:25] = rng.random((25, k1)) < 0.6
    I2[:25] = rng.random((25, k2)) < 0.6
    I1[25:] = rng.random((n - 25, k1)) < 0.03
    I2[25:] = rng.random((n - 25, k2)) < 0.03
    deep = 0
    for min_votes, max_pairs in ((2, 6), (4, 3), (3, 12)):
        lines, supports = rank_line_pairs(I1, I2, min_votes, max_pairs)
        ref = _rank_reference(I1, I2, min_votes, max_pairs)
        assert len(lines) == len(ref) > 0
        deep += len(ref) < max_pairs  # the cut, not max_pairs, ended the ranking
        for (i, j), sup, (ri, rj, rsup) in zip(lines, supports, ref, strict=True):
            assert (i, j) == (ri, rj)
            assert np.array_equal(np.flatnonzero(sup), rsup)
    assert deep > 0


def test_rank_line_pairs_without_enough_votes_is_empty():
    I1 = np.zeros((20, 3), bool)
    I2 = np.ones((20, 4), bool)
    lines, supports = rank_line_pairs(I1, I2, 4, 6)
    assert lines.shape == (0, 2) and supports.shape == (0, 20)


def test_scalar_line_homography_kernels_match_numpy_solvers():
    rng = np.random.default_rng(1)
    for _ in range(20):
        H = rng.normal(size=(2, 2))
        t1 = rng.uniform(-0.5, 1.5, 9)
        t2 = transfer(H, t1) + rng.normal(0, 1e-3, 9)
        ab1, ab2 = np.stack([1 - t1, t1], -1), np.stack([1 - t2, t2], -1)
        h = np.empty(4)
        line_homography_3pt_kernel(t1[:3], t2[:3], h)
        ref = line_homography_3pt(ab1[None, :3], ab2[None, :3])[0].ravel()
        assert min(np.abs(h - ref).max(), np.abs(h + ref).max()) < 1e-9
        lsq = line_homography_lsq_kernel(t1, t2, np.ones(9, bool))
        ref = line_homography_lsq(ab1, ab2).ravel()
        assert min(np.abs(lsq - ref).max(), np.abs(lsq + ref).max()) < 1e-9


def test_transfer_errors_match_numpy_transfer_and_line_homography_error():
    rng = np.random.default_rng(2)
    H = rng.normal(size=(2, 2))
    t1, t2 = rng.uniform(0, 1, 30), rng.uniform(0, 1, 30)
    out = np.empty(30)
    transfer_errors(H.ravel(), t1, t2, 300.0, 200.0, out)
    Hinv = np.array([[H[1, 1], -H[0, 1]], [-H[1, 0], H[0, 0]]])
    ref = 0.5 * (np.abs(transfer(H, t1) - t2) * 200.0 + np.abs(transfer(Hinv, t2) - t1) * 300.0)
    assert np.allclose(out, ref)
    # the public px error on points along two segments is the same quantity
    c1 = np.array([[0.0, 0.0], [300.0, 0.0]])
    c2 = np.array([[0.0, 10.0], [0.0, 210.0]])
    p1 = c1[0] + t1[:, None] * (c1[1] - c1[0])
    p2 = c2[0] + t2[:, None] * (c2[1] - c2[0])
    assert np.allclose(line_homography_error(H, (c1, c2), p1, p2), ref)


@pytest.mark.parametrize("seed", range(5))
def test_stage1_ransac_recovers_exact_line_homography_among_outliers(seed):
    rng = np.random.default_rng(seed)
    H = rng.normal(size=(2, 2))
    t1 = rng.uniform(0, 1, 40)
    t2 = transfer(H, t1)
    wrong = rng.random(40) < 0.4
    t2[wrong] = rng.uniform(0, 1, wrong.sum())
    u = rng.random((200, 3))
    h, found, hyps = stage1_ransac(t1, t2, 400.0, 400.0, 0.5, 0.99, u)
    assert found and 0 < hyps <= 200 + 200
    err = np.empty(40)
    transfer_errors(h, t1, t2, 400.0, 400.0, err)
    assert (err[~wrong] < 1e-6).all() and np.count_nonzero(err[wrong] < 0.5) <= 2
    assert np.allclose(transfer(h.reshape(2, 2), t1[~wrong]), t2[~wrong], atol=1e-9)
    # the uniforms are the only source of randomness: same numbers, same result
    h2, found2, hyps2 = stage1_ransac(t1, t2, 400.0, 400.0, 0.5, 0.99, u.copy())
    assert found2 and hyps2 == hyps and np.array_equal(h, h2)


def test_stage1_ransac_without_enough_points_finds_nothing():
    h, found, hyps = stage1_ransac(np.array([0.1, 0.2]), np.array([0.3, 0.4]), 1.0, 1.0, 0.5,
                                   0.99, np.random.default_rng(0).random((50, 3)))  # fmt: skip
    assert not found and hyps == 0


def _control_points_reference(line, image_size):
    """The plain numpy form: border intersections, the two farthest apart."""
    a, b, c = line
    w, h = image_size[0] - 1.0, image_size[1] - 1.0
    pts = [(u, -(a * u + c) / b) for u in (0.0, w) if abs(b) > 1e-12]
    pts += [(-(b * v + c) / a, v) for v in (0.0, h) if abs(a) > 1e-12]
    P = np.array(pts)
    inside = (P[:, 0] >= -1e-6) & (P[:, 0] <= w + 1e-6) & (P[:, 1] >= -1e-6) & (P[:, 1] <= h + 1e-6)
    Q = P[inside] if np.count_nonzero(inside) >= 2 else P
    d = np.linalg.norm(Q[:, None] - Q[None], axis=2)
    i, j = np.unravel_index(np.argmax(d), d.shape)
    return np.array([Q[i], Q[j]])


def test_control_points_are_the_farthest_border_intersections():
    rng = np.random.default_rng(3)
    size = (640, 480)
    lines = [np.array([1.0, 0.0, -100.0]), np.array([0.0, 1.0, -479.0]), np.array([0.6, 0.8, 5e3])]
    for _ in range(200):
        th = rng.uniform(0, np.pi)
        p = rng.uniform([0, 0], size)
        lines.append(np.array([np.cos(th), np.sin(th), -(np.cos(th) * p[0] + np.sin(th) * p[1])]))
    for line in lines:
        ctrl = control_points(line, size)
        assert np.allclose(ctrl, _control_points_reference(line, size))
        assert np.allclose(ctrl @ line[:2] + line[2], 0.0, atol=1e-6)  # both on the line


class _LineHomographyProblem(Problem):
    """Stage 1 written as a :class:`sepfm_ros.geometry.robust.contract.Problem` for the generic
    loop."""

    sample_size = 3

    def __init__(self, t1, t2, len1, len2, threshold):
        self.t1, self.t2, self.len1, self.len2, self.threshold = t1, t2, len1, len2, threshold
        self.n = len(t1)
        self.pool = np.arange(self.n)

    def _errors(self, h):
        err = np.empty(self.n)
        transfer_errors(h, self.t1, self.t2, self.len1, self.len2, err)
        return err

    def solve(self, samples):
        models, index = [], []
        for i, s in enumerate(samples):
            h = np.empty(4)
            line_homography_3pt_kernel(self.t1[s], self.t2[s], h)
            if abs(h[0] * h[3] - h[1] * h[2]) > 1e-9:
                models.append(h)
                index.append(i)
        return np.array(models).reshape(-1, 4), np.array(index, dtype=int)

    def score(self, models):
        err = np.array([self._errors(h) for h in models])
        cost = np.minimum(err * err, self.threshold**2).sum(axis=1)
        return cost, (err < self.threshold).sum(axis=1)

    def inliers(self, model):
        return self._errors(model) < self.threshold

    def local_optimize(self, model):
        inl = self._errors(model) < self.threshold
        if np.count_nonzero(inl) < 4:
            return np.empty((0, 4))
        return line_homography_lsq_kernel(self.t1, self.t2, inl)[None]


@pytest.mark.parametrize("seed", range(6))
def test_compiled_stage1_agrees_with_the_generic_ransac_loop(seed):
    """Parity of the compiled twin with ``run_ransac``: the same inliers and H_e on noisy line
    correspondences with outliers, and both stop at F(3, r) of the inlier ratio they found."""
    rng = np.random.default_rng(100 + seed)
    H = np.eye(2) + 0.3 * rng.normal(size=(2, 2))  # a line homography near the identity
    t1 = rng.uniform(0, 1, 60)
    t2 = transfer(H, t1) + rng.normal(0, 2e-4, 60)  # 0.08 px at 400 px per unit of t
    wrong = rng.random(60) < 0.3
    t2[wrong] = rng.uniform(0, 1, wrong.sum())
    h, found, hyps = stage1_ransac(t1, t2, 400.0, 400.0, 0.5, 0.99, rng.random((200, 3)))
    problem = _LineHomographyProblem(t1, t2, 400.0, 400.0, 0.5)
    ref = run_ransac([problem], np.random.default_rng(seed), 0.99, max_samples=200)
    assert found and ref.model is not None and ref.converged
    inl, inl_ref = problem._errors(h) < 0.5, problem._errors(ref.model) < 0.5
    for mask in (inl, inl_ref):  # both keep the true correspondences and reject the wrong ones
        assert np.count_nonzero(~mask & ~wrong) <= 1 and np.count_nonzero(mask & wrong) <= 2
    grid = np.linspace(0, 1, 11)
    assert np.allclose(transfer(h.reshape(2, 2), grid), transfer(ref.model.reshape(2, 2), grid),
                       atol=2e-3)  # fmt: skip
    need = trials_needed(3, int(np.count_nonzero(inl)), 60, 0.99, 200)
    assert need <= hyps and need <= sum(ref.samples)
    assert hyps <= 2 * need + 70 and sum(ref.samples) <= 2 * need + 70


def test_find_line_pairs_equals_its_steps():
    # find_line_pairs runs hough_lines, incidence and rank_line_pairs in two compiled calls:
    # the same lines, in the same order, with the same supports as the steps one by one
    from sepfm_ros.geometry.separable.line_pairs import find_line_pairs

    compared = 0
    for seed in range(8):
        rng = np.random.default_rng(seed)
        size1, size2 = (1024, 768), (800, 600)
        pts1 = _points_with_lines(rng, size1, n_lines=6, n_rand=int(rng.integers(50, 300)))
        pts2 = pts1 * 0.7 + rng.normal(0.0, 0.3, pts1.shape) + 20.0
        opts = LineSearchOptions(hough_points=int(rng.integers(100, 400)))
        got = find_line_pairs(pts1, pts2, size1, size2, opts)
        m = min(len(pts1), opts.hough_points)
        L1, L2 = hough_lines(pts1[:m], size1, opts), hough_lines(pts2[:m], size2, opts)
        I1, I2 = incidence(pts1, L1, size1, opts), incidence(pts2, L2, size2, opts)
        lines, supports = rank_line_pairs(I1, I2, opts.min_votes, opts.max_pairs)
        assert len(got) == len(lines)
        for pair, (i, j), sup in zip(got, lines, supports, strict=True):
            assert np.array_equal(pair.line1, L1[i]) and np.array_equal(pair.line2, L2[j])
            assert np.array_equal(pair.support, np.flatnonzero(sup))
            assert pair.support.dtype == np.int64
            compared += 1
    assert compared >= 16  # the comparison saw many line pairs
