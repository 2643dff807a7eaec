"""Compiled kernels of blob detection (:mod:`mocap.detect`): labelling, per-blob sums, fit windows and the disc fit.

Each computes what the numpy stages of :mod:`mocap.detect` compute, with one loop over the pixels of a frame
instead of dozens of numpy calls on small arrays; :mod:`mocap.detect` switches to them where
:data:`mocap.kernels.HAVE_NUMBA` is true. Same blobs in the same order, same pixels; sums in another order agree
to rounding (tests run both paths).
"""

from __future__ import annotations

import math

import numpy as np

from mocap.kernels import _jit

__all__ = ["label_blobs", "blob_sums", "fit_discs"]


# ---------------------------------------------------------------------------------------------- labelling
@_jit
def _bright_in_boxes(image, t, cell_labels, boxes, cell):
    """Number of pixels brighter than ``t`` in each group's own cells, summed over ``boxes`` (G, 5)."""
    h, w = image.shape
    total = 0
    for g in range(boxes.shape[0]):
        label = boxes[g, 0]
        for y in range(cell * boxes[g, 2], min(cell * (boxes[g, 4] + 1), h)):
            for x in range(cell * boxes[g, 1], min(cell * (boxes[g, 3] + 1), w)):
                if image[y, x] > t and cell_labels[y // cell, x // cell] == label:
                    total += 1
    return total


@_jit
def label_blobs(image, t, cell_labels, boxes, cell, owner, stamp):
    """8-connected blobs of the pixels brighter than ``t`` within each group of cells, group by group in the
    order of ``boxes`` (G, 5) ``label, cx0, cy0, cx1, cy1``, each group's blobs in the raster order of their first
    pixel (the numpy path's order: its mosaic labels patches in that order).

    ``owner`` (H, W) int64 is a scratch image kept between calls: a blob pixel gets ``stamp + blob + 1`` (``stamp``
    a multiple of 2^32, new for every call), so nothing needs clearing.

    Returns:
        starts (N + 1,): each blob's first pixel and the end; x, y (T,) int64, each blob's pixels in raster order;
        grey (T,) uint8.
    """
    h, w = image.shape
    total = _bright_in_boxes(image, t, cell_labels, boxes, cell)
    xs = np.empty(total, np.int64)
    ys = np.empty(total, np.int64)
    starts = np.empty(total + 1, np.int64)
    n = 0
    end = 0
    for g in range(boxes.shape[0]):
        label = boxes[g, 0]
        for y0 in range(cell * boxes[g, 2], min(cell * (boxes[g, 4] + 1), h)):
            for x0 in range(cell * boxes[g, 1], min(cell * (boxes[g, 3] + 1), w)):
                if image[y0, x0] <= t or cell_labels[y0 // cell, x0 // cell] != label or owner[y0, x0] > stamp:
                    continue
                starts[n] = end  # a new blob: breadth-first over its pixels, the list itself the queue
                mark = stamp + n + 1
                owner[y0, x0] = mark
                xs[end], ys[end] = x0, y0
                end += 1
                head = starts[n]
                while head < end:
                    px, py = xs[head], ys[head]
                    head += 1
                    for qy in range(max(py - 1, 0), min(py + 2, h)):
                        for qx in range(max(px - 1, 0), min(px + 2, w)):
                            if (owner[qy, qx] <= stamp and image[qy, qx] > t
                                    and cell_labels[qy // cell, qx // cell] == label):
                                owner[qy, qx] = mark
                                xs[end], ys[end] = qx, qy
                                end += 1
                order = np.argsort(ys[starts[n]:end] * w + xs[starts[n]:end])  # (distinct keys)
                xs[starts[n]:end] = xs[starts[n]:end][order]
                ys[starts[n]:end] = ys[starts[n]:end][order]
                n += 1
    starts[n] = end
    grey = np.empty(end, np.uint8)
    for i in range(end):
        grey[i] = image[ys[i], xs[i]]
    return starts[: n + 1], xs[:end], ys[:end], grey


@_jit
def blob_sums(starts, xs, ys, grey, level, saturated):
    """The numpy ``_Blobs`` sums, blob by blob (``starts`` (N + 1,), pixels as :func:`label_blobs` returns them):
    (N, 14) float64 columns ``area, flux, cx, cy, sxx, sxy, syy, vxx, vxy, vyy, peak, radius, saturated_radius,
    reach`` (``s``: weighted second moments / flux; ``v``: the centroid's noise covariance per unit noise
    variance)."""
    n = starts.shape[0] - 1
    out = np.empty((n, 14))
    for b in range(n):
        m0 = mx = my = 0.0
        peak = 0
        for i in range(starts[b], starts[b + 1]):
            wgt = max(grey[i] - level, 1e-6)
            m0 += wgt
            mx += wgt * xs[i]
            my += wgt * ys[i]
            peak = max(peak, grey[i])
        cx, cy = mx / m0, my / m0
        wxx = wxy = wyy = uxx = uxy = uyy = reach2 = 0.0
        half = 0
        sat = 0
        for i in range(starts[b], starts[b + 1]):
            wgt = max(grey[i] - level, 1e-6)
            dx, dy = xs[i] - cx, ys[i] - cy
            wxx += wgt * dx * dx
            wxy += wgt * dx * dy
            wyy += wgt * dy * dy
            uxx += dx * dx
            uxy += dx * dy
            uyy += dy * dy
            reach2 = max(reach2, dx * dx + dy * dy)
            half += grey[i] - level > 0.5 * (peak - level)
            sat += grey[i] >= saturated
        out[b, 0] = starts[b + 1] - starts[b]
        out[b, 1] = m0
        out[b, 2], out[b, 3] = cx, cy
        out[b, 4], out[b, 5], out[b, 6] = wxx / m0, wxy / m0, wyy / m0
        out[b, 7], out[b, 8], out[b, 9] = uxx / m0**2, uxy / m0**2, uyy / m0**2
        out[b, 10] = peak
        out[b, 11] = math.sqrt(half / math.pi)
        out[b, 12] = math.sqrt(sat / math.pi)
        out[b, 13] = math.sqrt(reach2)
    return out


# ---------------------------------------------------------------------------------------------- disc fit
@_jit
def _cholesky(A):
    """In place: the lower Cholesky factor of the symmetric (n, n) ``A``; False if it is not positive definite."""
    n = A.shape[0]
    for j in range(n):
        d = A[j, j]
        for k in range(j):
            d -= A[j, k] * A[j, k]
        if not d > 0.0:
            return False
        d = math.sqrt(d)
        A[j, j] = d
        for i in range(j + 1, n):
            v = A[i, j]
            for k in range(j):
                v -= A[i, k] * A[j, k]
            A[i, j] = v / d
    return True


@_jit
def _cholesky_solve(L, b, out):
    """``out`` = x with L L^T x = b (``L`` from :func:`_cholesky`)."""
    n = L.shape[0]
    for i in range(n):
        v = b[i]
        for k in range(i):
            v -= L[i, k] * out[k]
        out[i] = v / L[i, i]
    for i in range(n - 1, -1, -1):
        v = out[i]
        for k in range(i + 1, n):
            v -= L[k, i] * out[k]
        out[i] = v / L[i, i]


@_jit
def fit_discs(values, ox, oy, starts, params, iterations, tables, steps, z_res, z_origin, z_last, min_footprint,
              damping, step_bound, low, high):
    """Detection's ``_fit_discs`` (:mod:`mocap.detect`), blob by blob, pixel by pixel, in float64 (the numpy one
    runs its pixel arithmetic in float32: centres agree to ~1e-6 px). ``starts`` (N + 1,): each blob's first pixel
    and the end; ``params`` (N, 1 + 5K) float64 starts, updated in place; the edge ``tables``/``steps`` and the
    bounds as in :mod:`mocap.detect`. Returns the unscaled covariance (N, 1 + 5K, 1 + 5K) of the last step."""
    n, n_par = params.shape
    n_discs = (n_par - 1) // 5
    half = tables.shape[0] // 2
    cov_out = np.empty((n, n_par, n_par))
    J = np.empty(n_par)
    jtj = np.empty((n_par, n_par))
    grad = np.empty(n_par)
    z = np.empty(4)
    t = np.empty(4)
    dt = np.empty(4)
    lhs, damped = np.empty((n_par, n_par)), np.empty((n_par, n_par))
    step, unit, column = np.empty(n_par), np.empty(n_par), np.empty(n_par)
    for b in range(n):
        for step_no in range(iterations):
            jtj[:] = 0.0
            grad[:] = 0.0
            for p in range(starts[b], starts[b + 1]):
                model = params[b, 0]
                J[0] = 1.0
                for k in range(n_discs):
                    q = 1 + 5 * k
                    cx, cy, amp, r, s = (params[b, q], params[b, q + 1], params[b, q + 2], params[b, q + 3],
                                         params[b, q + 4])
                    dx, dy = ox[p] - cx, oy[p] - cy
                    rho = math.sqrt(dx * dx + dy * dy)
                    inv_rho = 1.0 / max(rho, 1e-6)
                    a = max(abs(dx) * inv_rho, min_footprint)  # the pixel's footprint across the edge
                    bb = max(abs(dy) * inv_rho, min_footprint)
                    inv_s = 1.0 / s
                    depth = r - rho
                    inside = depth > 0.0
                    centre = depth * (z_res * inv_s) + z_origin
                    half_sum, half_diff = (a + bb) * (0.5 * z_res * inv_s), abs(a - bb) * (0.5 * z_res * inv_s)
                    z[0], z[1] = centre + half_sum, centre + half_diff
                    z[2], z[3] = centre - half_diff, centre - half_sum
                    for i in range(4):
                        zi = min(max(z[i], 0.0), z_last)
                        cell = int(zi)  # (zi >= 0: the floor)
                        index = cell + (half if inside else 0)
                        dt[i] = steps[index]
                        t[i] = tables[index] + (zi - cell) * dt[i]
                        z[i] = (zi - z_origin) * dt[i]  # z T'(z), scaled as the numpy one
                    sum_t = (t[0] + t[3]) - (t[1] + t[2])
                    scale = s / (a * bb)
                    f = sum_t * scale * s + (1.0 if inside else 0.0)
                    slope = ((dt[0] + dt[3]) - (dt[1] + dt[2])) * (scale * z_res) * amp
                    model += amp * f
                    J[q + 2] = f
                    J[q + 4] = amp * scale * (2.0 * sum_t - ((z[0] + z[3]) - (z[1] + z[2])))
                    J[q + 3] = slope
                    J[q] = slope * inv_rho * dx
                    J[q + 1] = slope * inv_rho * dy
                resid = values[p] - model
                for i in range(n_par):
                    grad[i] += J[i] * resid
                    for j in range(i, n_par):
                        jtj[i, j] += J[i] * J[j]
            for i in range(n_par):
                for j in range(i):
                    jtj[i, j] = jtj[j, i]
            if step_no < iterations - 1:
                damped[:] = jtj
                for i in range(n_par):
                    damped[i, i] = damped[i, i] * (1.0 + damping) + 1e-9
                lhs[:] = damped  # (factored in place)
                if _cholesky(lhs):
                    _cholesky_solve(lhs, grad, step)
                else:
                    step[:] = np.linalg.solve(damped, grad)
            else:  # the last step is undamped: its inverse is also the covariance
                lhs[:] = jtj
                if _cholesky(lhs):
                    for i in range(n_par):
                        unit[:] = 0.0
                        unit[i] = 1.0
                        _cholesky_solve(lhs, unit, column)
                        cov_out[b, :, i] = column
                else:  # a degenerate window
                    cov_out[b] = np.linalg.pinv(jtj)
                step[:] = cov_out[b] @ grad
            params[b, 0] += step[0]
            for k in range(n_discs):
                for i in range(5):
                    q = 1 + 5 * k + i
                    v = params[b, q] + min(max(step[q], -step_bound[i]), step_bound[i])
                    params[b, q] = min(max(v, low[i]), high[i])
    return cov_out
