"""Line-pair search (paper Sec. 4): Hough lines on binary images of the matched points and the
joint accumulator A(m, n) = number of correspondences whose point in image 1 lies on line m and
whose point in image 2 lies on line n.

The paper's accumulator is N x K1 x K2; summed over the correspondences it is the product of the
two point-line incidence matrices, A = I1^T I2 (K1 x K2), which a compiled kernel builds from each
correspondence's (line, line) incidences and ranks (see :func:`rank_line_pairs`). The Hough
transform votes the pixels of the binary image directly (a point-set Hough transform, which gives
the lines of ``cv2.HoughLines`` on that image without scanning it): :func:`hough_point_set` is
``cv2.HoughLinesPointSet``'s arithmetic (float32 votes, its local-maximum rule and its order,
tested equal to it line for line) in a compiled kernel that keeps three rows of the accumulator
and examines only the cells that were voted for. OpenCV's call clears and scans the whole
accumulator (about 1,240 x 180 cells at the 512 px working width) for a few hundred points,
which made it most of the line search's time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from sepfm_ros.geometry.separable.options import LineSearchOptions


@dataclass(frozen=True)
class LinePair:
    """Two corresponding image lines and the correspondences on both.

    line1, line2: (3,) lines (a, b, c) in pixels of image 1 / 2, a u + b v + c = 0, a^2 + b^2 = 1.
    support: (K,) indices of the correspondences within C of both lines.
    """

    line1: np.ndarray
    line2: np.ndarray
    support: np.ndarray


def working_scale(image_size: tuple[float, float], width: int) -> float:
    """Scale factor from image pixels to the working resolution (working width / image width)."""
    return float(width) / float(image_size[0])


def hough_lines(
    pts: np.ndarray, image_size: tuple[float, float], opts: LineSearchOptions
) -> np.ndarray:
    """Lines through the points, strongest first.

    Args:
        pts: (N, 2) pixel coordinates (only these are drawn).
        image_size: (width, height) in px.
    Returns:
        (L, 3) lines in image pixels (a, b, c), a^2 + b^2 = 1, L <= opts.max_lines.
    """
    s = working_scale(image_size, opts.width)
    w = max(1, int(np.ceil(image_size[0] * s)))
    h = max(1, int(np.ceil(image_size[1] * s)))
    found = _hough_of_points(
        np.ascontiguousarray(pts, dtype=np.float64), s, w, h, int(opts.max_lines),
        int(opts.min_votes),
    )  # fmt: skip
    return _lines_in_pixels(found, s)


def _lines_in_pixels(found: np.ndarray, scale: float) -> np.ndarray:
    """(L, 3) (votes, rho working px, theta rad) -> (L, 3) lines (cos, sin, -rho / scale) in
    image px. (numpy's cos and sin, not a kernel's: the lines stay bit-identical.)"""
    if len(found) == 0:
        return np.zeros((0, 3))
    rho, theta = found[:, 1], found[:, 2]
    return np.stack([np.cos(theta), np.sin(theta), -rho / scale], axis=1)


@numba.njit(cache=True, nogil=True)
def _hough_of_points(
    pts: np.ndarray, scale: float, w: int, h: int, max_lines: int, min_votes: int
) -> np.ndarray:
    """Hough lines of the binary image of (N, 2) points at ``scale`` in a w x h image
    (:func:`binary_image_pixels`, then :func:`hough_point_set` over the rho range the image
    can produce for theta in [0, pi): x cos + y sin in [-(w - 1), hypot(w, h)]).

    Returns:
        (L, 3) (votes, rho working px, theta rad), strongest first, L <= max_lines.
    """
    xy = binary_image_pixels(pts, scale, w, h)
    if xy.shape[0] == 0:
        return np.zeros((0, 3))
    return hough_point_set(
        xy.reshape(-1, 2), max_lines, min_votes, float(-w), float(np.ceil(np.hypot(w, h))),
        1.0, 0.0, np.pi, np.pi / 180.0,
    )  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _hough_of_both(
    pts1: np.ndarray,
    scale1: float,
    w1: int,
    h1: int,
    pts2: np.ndarray,
    scale2: float,
    w2: int,
    h2: int,
    max_lines: int,
    min_votes: int,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_hough_of_points` of image 1 and of image 2, in one call."""
    return (
        _hough_of_points(pts1, scale1, w1, h1, max_lines, min_votes),
        _hough_of_points(pts2, scale2, w2, h2, max_lines, min_votes),
    )


@numba.njit(cache=True, nogil=True)
def binary_image_pixels(pts: np.ndarray, scale: float, w: int, h: int) -> np.ndarray:
    """The set pixels of the binary image of (N, 2) points at ``scale`` in a w x h image.

    Returns:
        (M, 1, 2) float32 pixel coordinates (x, y), each set pixel once, in raster order (points
        rounded to the nearest pixel; points outside the image are dropped).
    """
    keys = np.empty(len(pts), dtype=np.int64)
    k = 0
    for i in range(len(pts)):
        x = np.rint(pts[i, 0] * scale)
        y = np.rint(pts[i, 1] * scale)
        if x >= 0 and x < w and y >= 0 and y < h:
            keys[k] = int(y) * w + int(x)
            k += 1
    keys = np.sort(keys[:k])
    out = np.empty((k, 1, 2), dtype=np.float32)
    m = 0
    for i in range(k):
        if i == 0 or keys[i] != keys[i - 1]:
            out[m, 0, 0] = keys[i] % w
            out[m, 0, 1] = keys[i] // w
            m += 1
    return out[:m]


@numba.njit(cache=True, nogil=True)
def hough_point_set(
    xy: np.ndarray,
    lines_max: int,
    threshold: int,
    min_rho: float,
    max_rho: float,
    rho_step: float,
    min_theta: float,
    max_theta: float,
    theta_step: float,
) -> np.ndarray:
    """Hough lines through a point set: ``cv2.HoughLinesPointSet``'s result, computed sparsely.

    Same arithmetic as OpenCV's (float32 trigonometric table and votes, round half to even),
    same local maxima (a cell with more than ``threshold`` votes, more than its lower rho and
    angle neighbours and at least its upper ones) and the same order (votes descending, then
    angle index, then rho index). The accumulator is kept as three rolling angle rows, and
    only the cells whose votes passed the threshold are examined, so the cost grows with
    points x angles instead of with the accumulator's size.

    Args:
        xy: (M, 2) float32 points (x, y), px.
        lines_max: most lines returned. threshold: votes a line must exceed.
        min_rho, max_rho, rho_step: rho range and bin, px. min_theta, max_theta, theta_step:
            angle range and bin, rad.
    Returns:
        (L, 3) float64 (votes, rho px, theta rad), strongest first, L <= lines_max.
    """
    irho = np.float32(1.0) / np.float32(rho_step)
    irho_min = np.float32(min_rho) * irho
    numangle = int(np.floor((max_theta - min_theta) / theta_step)) + 1
    if numangle > 1 and abs(np.pi - (numangle - 1) * theta_step) < theta_step / 2:
        numangle -= 1
    numrho = int(np.rint((max_rho - min_rho + 1.0) / rho_step))
    stride = numrho + 2
    tab_cos = np.empty(numangle, dtype=np.float32)
    tab_sin = np.empty(numangle, dtype=np.float32)
    ang = np.float32(min_theta)
    for n in range(numangle):
        tab_sin[n] = np.float32(np.sin(np.float64(ang)) * np.float64(irho))
        tab_cos[n] = np.float32(np.cos(np.float64(ang)) * np.float64(irho))
        ang = np.float32(ang + np.float32(theta_step))
    M = xy.shape[0]
    x = xy[:, 0].copy()
    y = xy[:, 1].copy()
    rho_f = np.empty(M, dtype=np.float32)
    rows = np.zeros((3, stride), dtype=np.int32)  # angle rows n - 1, n, n + 1 (mod 3)
    cols = np.empty((3, M), dtype=np.int32)  # each point's accumulator column in that row
    # per row, the cells whose votes passed the threshold (at most M // (threshold + 1))
    per_row = M // (max(threshold, 0) + 1) + 1
    hot = np.empty((3, per_row), dtype=np.int32)
    n_hot = np.zeros(3, dtype=np.int64)
    cand_votes = np.empty(numangle * per_row, dtype=np.int64)
    cand_base = np.empty(numangle * per_row, dtype=np.int64)
    n_cand = 0
    for n in range(-1, numangle):
        nxt = n + 1
        if nxt < numangle:  # vote row n + 1
            slot = nxt % 3
            row, col, row_hot = rows[slot], cols[slot], hot[slot]
            c_n, s_n = tab_cos[nxt], tab_sin[nxt]
            for i in range(M):
                rho_f[i] = np.rint(x[i] * c_n + y[i] * s_n - irho_min)  # half to even
            k = 0
            for i in range(M):
                r = np.int32(rho_f[i])
                if 0 <= r <= numrho:
                    col[i] = r + 1
                    row[r + 1] += 1
                    if row[r + 1] == threshold + 1 and r < numrho:  # numrho: OpenCV's margin
                        row_hot[k] = r + 1
                        k += 1
                else:
                    col[i] = -1
            n_hot[slot] = k
        if n < 0:
            continue
        slot = n % 3
        cur, up, low = rows[slot], rows[(n + 1) % 3], rows[(n + 2) % 3]
        for j in range(n_hot[slot]):
            c = hot[slot, j]
            v = cur[c]
            lo_v = low[c] if n > 0 else 0
            up_v = up[c] if n + 1 < numangle else 0
            if v > cur[c - 1] and v >= cur[c + 1] and v > lo_v and v >= up_v:
                cand_votes[n_cand] = v
                cand_base[n_cand] = (n + 1) * stride + c
                n_cand += 1
        if n > 0:  # row n - 1 is done: clear the cells it voted for, for row n + 2
            row, col = rows[(n + 2) % 3], cols[(n + 2) % 3]
            for i in range(M):
                c = col[i]
                if c >= 0:
                    row[c] = 0
    votes, base = cand_votes[:n_cand], cand_base[:n_cand]
    order = np.argsort(base)  # ties in votes: smaller index first, as OpenCV's sort
    order = order[np.argsort(-votes[order], kind="mergesort")]
    L = min(lines_max, n_cand)
    out = np.empty((L, 3))
    for k in range(L):
        b = base[order[k]]
        n = b // stride - 1
        r = b - (n + 1) * stride - 1
        out[k, 0] = votes[order[k]]
        out[k, 1] = np.float32(np.float32(min_rho) + np.float32(r) * np.float32(rho_step))
        out[k, 2] = np.float32(np.float32(min_theta) + np.float32(n) * np.float32(theta_step))
    return out


def incidence(
    pts: np.ndarray, lines: np.ndarray, image_size: tuple[float, float], opts: LineSearchOptions
) -> np.ndarray:
    """(N, L) bool: point i within C (working-resolution px) of line j."""
    s = working_scale(image_size, opts.width)
    return _incidence(
        np.ascontiguousarray(pts, dtype=np.float64),
        np.ascontiguousarray(lines, dtype=np.float64),
        float(opts.distance) / s,
    )


@numba.njit(cache=True, nogil=True)
def _incidence(pts: np.ndarray, lines: np.ndarray, dist: float) -> np.ndarray:
    """(N, L) bool: |a u + b v + c| < dist (px of the image) for points (N, 2), lines (L, 3)."""
    out = np.empty((len(pts), len(lines)), dtype=np.bool_)
    for i in range(len(pts)):
        u, v = pts[i, 0], pts[i, 1]
        for j in range(len(lines)):
            out[i, j] = abs(lines[j, 0] * u + lines[j, 1] * v + lines[j, 2]) < dist
    return out


def find_line_pairs(
    pts1: np.ndarray,
    pts2: np.ndarray,
    image_size1: tuple[float, float],
    image_size2: tuple[float, float],
    opts: LineSearchOptions | None = None,
) -> list[LinePair]:
    """Candidate line pairs ranked by joint count (paper Sec. 4, extended to several pairs).

    Pairs are taken greedily in decreasing joint count; a pair whose support shares more than
    half of its correspondences with an already chosen pair is skipped (Hough returns many
    near-duplicate lines through the same points). Only pairs with at least ``min_votes``
    correspondences are returned.

    Args:
        pts1, pts2: (N, 2) matched points in pixels, best matches first.
    """
    opts = opts or LineSearchOptions()
    p1 = np.ascontiguousarray(pts1, dtype=np.float64)
    p2 = np.ascontiguousarray(pts2, dtype=np.float64)
    m = min(len(p1), opts.hough_points)
    # the steps of hough_lines, incidence and rank_line_pairs in two compiled calls (the
    # Python between them was about a quarter of the search's time on SIFT pairs)
    s1, s2 = working_scale(image_size1, opts.width), working_scale(image_size2, opts.width)
    w1, h1 = max(1, int(np.ceil(image_size1[0] * s1))), max(1, int(np.ceil(image_size1[1] * s1)))
    w2, h2 = max(1, int(np.ceil(image_size2[0] * s2))), max(1, int(np.ceil(image_size2[1] * s2)))
    found1, found2 = _hough_of_both(
        p1[:m], s1, w1, h1, p2[:m], s2, w2, h2, int(opts.max_lines), int(opts.min_votes)
    )
    if len(found1) == 0 or len(found2) == 0:
        return []
    L1, L2 = _lines_in_pixels(found1, s1), _lines_in_pixels(found2, s2)
    lines, start, support = _rank_lines_of_points(
        p1, L1, float(opts.distance) / s1, p2, L2, float(opts.distance) / s2,
        int(opts.min_votes), int(opts.max_pairs),
    )  # fmt: skip
    return [
        LinePair(L1[i], L2[j], support[start[k] : start[k + 1]]) for k, (i, j) in enumerate(lines)
    ]


@numba.njit(cache=True, nogil=True)
def _rank_lines_of_points(
    pts1: np.ndarray,
    L1: np.ndarray,
    dist1: float,
    pts2: np.ndarray,
    L2: np.ndarray,
    dist2: float,
    min_votes: int,
    max_pairs: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`incidence` in both images and :func:`rank_line_pairs`, in one call.

    Args:
        pts1, pts2: (N, 2) px. L1: (K1, 3), L2: (K2, 3) lines in px. dist1, dist2: C in px of
            each image.
    Returns:
        (P, 2) line indices (m, n); start (P + 1,) and support (S,): pair p's correspondences
        (ascending) are ``support[start[p]:start[p + 1]]``.
    """
    I1 = _incidence(pts1, L1, dist1)
    I2 = _incidence(pts2, L2, dist2)
    lines, supports = rank_line_pairs(I1, I2, min_votes, max_pairs)
    P, N = supports.shape
    start = np.zeros(P + 1, dtype=np.int64)
    for p in range(P):
        start[p + 1] = start[p] + np.count_nonzero(supports[p])
    support = np.empty(start[P], dtype=np.int64)
    k = 0
    for p in range(P):
        for j in range(N):
            if supports[p, j]:
                support[k] = j
                k += 1
    return lines, start, support


@numba.njit(cache=True, nogil=True)
def rank_line_pairs(
    I1: np.ndarray, I2: np.ndarray, min_votes: int, max_pairs: int
) -> tuple[np.ndarray, np.ndarray]:
    """Joint accumulator A = I1^T I2 and the greedy ranking of :func:`find_line_pairs`, compiled.

    A(m, n) counts the correspondences on line m in image 1 and line n in image 2 (the paper's
    N x K1 x K2 accumulator summed over N, built from each correspondence's d1 x d2 line
    incidences). Pairs are taken in decreasing count (ties: smaller m * K2 + n first) among the
    ``20 * max_pairs`` best with at least ``min_votes``; a pair sharing more than half of its
    support with already chosen pairs is skipped.

    Args:
        I1: (N, K1) bool incidence in image 1. I2: (N, K2) bool incidence in image 2.
    Returns:
        (P, 2) line indices (m, n) and (P, N) bool supports of the chosen pairs, P <= max_pairs.
    """
    N, K1 = I1.shape
    K2 = I2.shape[1]
    A = np.zeros(K1 * K2, dtype=np.int64)
    # correspondences on each line of image 1 (CSR, ascending), built in the same pass
    col_count = np.zeros(K1 + 1, dtype=np.int64)
    on2 = np.empty(K2, dtype=np.int64)
    for j in range(N):
        d2 = 0
        for n in range(K2):
            if I2[j, n]:
                on2[d2] = n
                d2 += 1
        for m in range(K1):
            if I1[j, m]:
                col_count[m + 1] += 1
                for k in range(d2):
                    A[m * K2 + on2[k]] += 1
    start = np.cumsum(col_count)
    col = np.empty(start[K1], dtype=np.int64)
    fill = start[:K1].copy()
    for j in range(N):
        for m in range(K1):
            if I1[j, m]:
                col[fill[m]] = j
                fill[m] += 1
    # the 20 * max_pairs best: only the counts at or above the count that ranks there are
    # sorted (a histogram of the counts finds it; sorting every pair above min_votes cost more
    # than the accumulator)
    top = 20 * max_pairs
    hist = np.zeros(N + 1, dtype=np.int64)
    for cell in range(K1 * K2):
        hist[A[cell]] += 1
    low, above = max(N, min_votes), 0
    while low > min_votes and above + hist[low] < top:
        above += hist[low]
        low -= 1
    cand = np.flatnonzero(A >= low)
    cand = cand[np.argsort(-A[cand], kind="mergesort")][:top]
    lines = np.zeros((max_pairs, 2), dtype=np.int64)
    supports = np.zeros((max_pairs, N), dtype=np.bool_)
    used = np.zeros(N, dtype=np.bool_)
    P = 0
    for c in cand:
        if P >= max_pairs:
            break
        m, n = c // K2, c % K2
        shared = 0
        for k in range(start[m], start[m + 1]):
            j = col[k]
            if I2[j, n] and used[j]:
                shared += 1
        if shared * 2 > A[c]:
            continue
        for k in range(start[m], start[m + 1]):
            j = col[k]
            if I2[j, n]:
                supports[P, j] = True
                used[j] = True
        lines[P, 0], lines[P, 1] = m, n
        P += 1
    return lines[:P], supports[:P]


def control_points(line: np.ndarray, image_size: tuple[float, float]) -> np.ndarray:
    """The paper's control points: where ``line`` meets the image border.

    Args:
        line: (3,) (a, b, c) in pixels. image_size: (width, height).
    Returns:
        (2, 2) the two border points farthest apart (pixel centres span [0, w-1] x [0, h-1]);
        for a line missing the image, the two points of the line closest to the image corners.
    """
    a, b, c = (float(v) for v in line)
    return _control_points(a, b, c, float(image_size[0]) - 1.0, float(image_size[1]) - 1.0)


@numba.njit(cache=True, nogil=True)
def _control_points(a: float, b: float, c: float, w: float, h: float) -> np.ndarray:
    """:func:`control_points` of line (a, b, c) in [0, w] x [0, h], compiled."""
    P = np.empty((4, 2))
    n = 0
    if abs(b) > 1e-12:
        for u in (0.0, w):
            P[n, 0], P[n, 1] = u, -(a * u + c) / b
            n += 1
    if abs(a) > 1e-12:
        for v in (0.0, h):
            P[n, 0], P[n, 1] = -(b * v + c) / a, v
            n += 1
    inside = np.zeros(n, dtype=np.bool_)
    k = 0
    for i in range(n):
        x, y = P[i, 0], P[i, 1]
        inside[i] = x >= -1e-6 and x <= w + 1e-6 and y >= -1e-6 and y <= h + 1e-6
        if inside[i]:
            k += 1
    Q = P[:n][inside] if k >= 2 else P[:n]
    bi, bj, best = 0, 0, -1.0
    for i in range(len(Q)):
        for j in range(len(Q)):
            d = np.hypot(Q[i, 0] - Q[j, 0], Q[i, 1] - Q[j, 1])
            if d > best:
                bi, bj, best = i, j, d
    out = np.empty((2, 2))
    if best < 1e-9:  # degenerate: use a unit segment along the line
        out[0, 0], out[0, 1] = -c * a, -c * b
        out[1, 0], out[1, 1] = -c * a - b, -c * b + a
        return out
    out[0] = Q[bi]
    out[1] = Q[bj]
    return out


def line_parameter(pts: np.ndarray, ctrl: np.ndarray) -> np.ndarray:
    """Parameter t of the projection of (K, 2) points onto segment ctrl (2, 2): c1 + t (c2 - c1)."""
    d = ctrl[1] - ctrl[0]
    return (pts - ctrl[0]) @ d / (d @ d)
