"""Compiled kernels of blob detection (:mod:`mocap.detect`): background tiles, coarse pass, labelling, per-blob
sums, neighbour medians, peaks, fit windows, the disc fit and its checks, the cut disc fit.

Each computes what the numpy stages of :mod:`mocap.detect` compute, with one loop over the pixels of a frame
instead of dozens of numpy calls on small arrays; :mod:`mocap.detect` switches to them where
:data:`mocap.kernels.HAVE_NUMBA` is true. Same blobs in the same order, same pixels; sums in another order agree
to rounding (tests run both paths).
"""

from __future__ import annotations

import math

import numpy as np

from mocap.kernels import _jit

__all__ = ["subsampled_histogram", "tile_quantiles", "coarse_groups", "label_blobs", "blob_sums",
           "neighbour_medians", "peaks", "window", "fit_discs", "fit_results", "fit_cut_discs"]


# ---------------------------------------------------------------------------------------------- coarse search
@_jit
def subsampled_histogram(image, step):
    """(256,) float64 counts of the grey levels of every ``step``-th pixel of every ``step``-th row."""
    h, w = image.shape
    counts = np.zeros(256, np.int64)
    for y in range(0, h, step):
        for x in range(0, w, step):
            counts[image[y, x]] += 1
    return counts.astype(np.float64)


@_jit
def tile_quantiles(image, step, side, q_low):
    """The numpy ``_tile_medians``' per-tile levels: of every ``step``-th pixel of every ``step``-th row, grouped in
    tiles of ``side`` such samples a side, each tile's lowest grey level whose cumulative count reaches half its
    samples, and ``q_low`` of them. Returns (ty, tx) int64 medians and (ty, tx) int64 low quantiles."""
    h, w = image.shape
    hs, ws = (h + step - 1) // step, (w + step - 1) // step
    ty, tx = (hs + side - 1) // side, (ws + side - 1) // side
    counts = np.zeros((ty, tx, 256), np.int32)
    for i in range(hs):
        row = image[i * step]
        for j in range(ws):
            counts[i // side, j // side, row[j * step]] += 1
    medians, lows = np.empty((ty, tx), np.int64), np.empty((ty, tx), np.int64)
    for a in range(ty):
        for b in range(tx):
            total = 0
            for k in range(256):
                total += counts[a, b, k]
            cum, low, med = 0, -1, -1
            for k in range(256):
                cum += counts[a, b, k]
                if low < 0 and cum >= q_low * total:
                    low = k
                if cum >= 0.5 * total:
                    med = k
                    break
            medians[a, b], lows[a, b] = med, low
    return medians, lows


@_jit
def coarse_groups(image, t, cell):
    """The numpy ``_max_pool`` + ``_groups``: cells (``cell`` x ``cell`` px, the last row and column of cells
    cut by the border) holding a pixel brighter than ``t``, and their 8-connected groups, labelled as OpenCV's
    Grana algorithm labels them: in the raster order of their first 2x2 block of cells.

    Returns:
        labels (Hc, Wc) int32 (0: no group) and boxes (G, 5) int64 ``label, cx0, cy0, cx1, cy1`` (inclusive).
    """
    h, w = image.shape
    hc, wc = (h + cell - 1) // cell, (w + cell - 1) // cell
    hot = np.zeros((hc, wc), np.bool_)
    hot_row = np.zeros(hc, np.bool_)
    level = np.uint8(min(t, 255))
    column_max = np.zeros(w, np.uint8)  # each column's brightest pixel in the bright rows of a row of cells
    for cy in range(hc):
        for y in range(cy * cell, min(cy * cell + cell, h)):
            src = image[y]
            bright = False
            for x in range(w):  # (branch-free loops the compiler vectorises: most rows hold no marker)
                bright |= src[x] > level
            if bright:
                hot_row[cy] = True
                for x in range(w):
                    column_max[x] = max(column_max[x], src[x])
        if hot_row[cy]:
            for x in range(w):
                if column_max[x] > level:
                    hot[cy, x // cell] = True
                column_max[x] = 0
    rows = np.flatnonzero(hot_row)
    n_hot = 0
    for cy in rows:
        for cx in range(wc):
            n_hot += hot[cy, cx]
    labels = np.zeros((hc, wc), np.int32)
    queue_x, queue_y = np.empty(n_hot, np.int64), np.empty(n_hot, np.int64)
    boxes = np.empty((n_hot, 5), np.int64)
    first_block = np.empty(n_hot, np.int64)
    n = 0
    for cy in rows:
        for cx in range(wc):
            if not hot[cy, cx] or labels[cy, cx] != 0:
                continue
            n += 1
            labels[cy, cx] = n
            boxes[n - 1] = (n, cx, cy, cx, cy)
            first_block[n - 1] = (cy // 2) * wc + cx // 2
            queue_x[0], queue_y[0] = cx, cy
            head, end = 0, 1
            while head < end:
                px, py = queue_x[head], queue_y[head]
                head += 1
                boxes[n - 1, 1] = min(boxes[n - 1, 1], px)
                boxes[n - 1, 3] = max(boxes[n - 1, 3], px)
                boxes[n - 1, 4] = max(boxes[n - 1, 4], py)
                first_block[n - 1] = min(first_block[n - 1], (py // 2) * wc + px // 2)
                for qy in range(max(py - 1, 0), min(py + 2, hc)):
                    for qx in range(max(px - 1, 0), min(px + 2, wc)):
                        if hot[qy, qx] and labels[qy, qx] == 0:
                            labels[qy, qx] = n
                            queue_x[end], queue_y[end] = qx, qy
                            end += 1
    order = np.argsort(first_block[:n])  # (distinct: the cells of a 2x2 block touch)
    new_label = np.zeros(n + 1, np.int32)
    for rank in range(n):
        new_label[order[rank] + 1] = rank + 1
    for cy in rows:
        for cx in range(wc):
            labels[cy, cx] = new_label[labels[cy, cx]]
    boxes = boxes[order]
    boxes[:, 0] = np.arange(1, n + 1)
    return labels, boxes


# ---------------------------------------------------------------------------------------------- labelling
@_jit
def label_blobs(image, t, cell_labels, boxes, cell):
    """8-connected blobs of the pixels brighter than ``t`` within each group of cells, group by group in the
    order of ``boxes`` (G, 5) ``label, cx0, cy0, cx1, cy1``, each group's blobs in the raster order of their first
    pixel (the numpy path's order: its mosaic labels patches in that order).

    Returns:
        starts (N + 1,): each blob's first pixel and the end; x, y (T,) int64, each blob's pixels in raster order;
        grey (T,) uint8; and which blob owns a pixel, as ``mocap.detect._Owners`` holds it: ``labels`` (L,) int32
        (every group's box of pixels one after another, blob id + 1 or 0) and per blob (N,) its box's ``base``
        index there, top-left ``x0``, ``y0``, ``width`` and ``height``, and its label there ``local`` (N,) int32.
    """
    h, w = image.shape
    n_groups = boxes.shape[0]
    gx0, gy0 = np.empty(n_groups, np.int64), np.empty(n_groups, np.int64)
    gw, gh, gbase = np.empty(n_groups, np.int64), np.empty(n_groups, np.int64), np.empty(n_groups, np.int64)
    total = area = 0
    for g in range(n_groups):
        gx0[g], gy0[g] = cell * boxes[g, 1], cell * boxes[g, 2]
        gw[g] = min(cell * (boxes[g, 3] + 1), w) - gx0[g]
        gh[g] = min(cell * (boxes[g, 4] + 1), h) - gy0[g]
        gbase[g] = area
        area += gw[g] * gh[g]
        for y in range(gy0[g], gy0[g] + gh[g]):
            for x in range(gx0[g], gx0[g] + gw[g]):
                if image[y, x] > t and cell_labels[y // cell, x // cell] == boxes[g, 0]:
                    total += 1
    labels = np.zeros(area, np.int32)
    xs, ys = np.empty(total, np.int64), np.empty(total, np.int64)
    starts, group = np.empty(total + 1, np.int64), np.empty(total, np.int64)
    n = end = 0
    for g in range(n_groups):
        label, x_lo, y_lo, pw, ph, base = boxes[g, 0], gx0[g], gy0[g], gw[g], gh[g], gbase[g]
        for y0 in range(y_lo, y_lo + ph):
            for x0 in range(x_lo, x_lo + pw):
                if (image[y0, x0] <= t or cell_labels[y0 // cell, x0 // cell] != label
                        or labels[base + (y0 - y_lo) * pw + x0 - x_lo] != 0):
                    continue
                starts[n], group[n] = end, g  # a new blob: breadth-first over its pixels, the list itself the queue
                labels[base + (y0 - y_lo) * pw + x0 - x_lo] = n + 1
                xs[end], ys[end] = x0, y0
                end += 1
                head = starts[n]
                while head < end:
                    px, py = xs[head], ys[head]
                    head += 1
                    for qy in range(max(py - 1, y_lo), min(py + 2, y_lo + ph)):
                        for qx in range(max(px - 1, x_lo), min(px + 2, x_lo + pw)):
                            at = base + (qy - y_lo) * pw + qx - x_lo
                            if labels[at] == 0 and image[qy, qx] > t and cell_labels[qy // cell, qx // cell] == label:
                                labels[at] = n + 1
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
    g = group[:n]
    return (starts[: n + 1], xs[:end], ys[:end], grey, labels, gbase[g], gx0[g], gy0[g], gw[g], gh[g],
            np.arange(1, n + 1).astype(np.int32))


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


# ---------------------------------------------------------------------------------------------- neighbours
@_jit
def neighbour_medians(xy, values, k):
    """(N, V) median of each of the ``values`` (N, V) over each blob's ``k`` nearest other blobs (centres ``xy``
    (N, 2) px), as :func:`mocap.detect._neighbour_medians` computes it from all pairwise distances: the ``k`` smallest
    squared distances, ties to the lower index (a stable sort's first ``k``)."""
    n, nv = values.shape
    out = np.empty((n, nv))
    best_d = np.empty(k)
    best_j = np.empty(k, np.int64)
    near = np.empty(k)
    for i in range(n):
        filled = 0
        for j in range(n):
            if j == i:
                continue
            dx = xy[i, 0] - xy[j, 0]
            dy = xy[i, 1] - xy[j, 1]
            d = dx * dx + dy * dy
            if filled == k and d >= best_d[k - 1]:  # (an equal distance at a higher index does not displace)
                continue
            m = filled if filled < k else k - 1  # insertion into the sorted best list
            while m > 0 and best_d[m - 1] > d:
                best_d[m] = best_d[m - 1]
                best_j[m] = best_j[m - 1]
                m -= 1
            best_d[m] = d
            best_j[m] = j
            if filled < k:
                filled += 1
        for v in range(nv):
            for m in range(k):  # insertion sort of the k values
                x = values[best_j[m], v]
                q = m
                while q > 0 and near[q - 1] > x:
                    near[q] = near[q - 1]
                    q -= 1
                near[q] = x
            out[i, v] = 0.5 * (near[(k - 1) // 2] + near[k // 2])
    return out


# ---------------------------------------------------------------------------------------------- peaks
@_jit
def _smooth(image, x, y):
    """The 3x3 mean of ``image`` around (x, y) (pixels beyond the border repeat it), in float32 as numpy's."""
    h, w = image.shape
    total = 0
    for qy in range(y - 1, y + 2):
        for qx in range(x - 1, x + 2):
            total += image[min(max(qy, 0), h - 1), min(max(qx, 0), w - 1)]
    return np.float32(total) * np.float32(1.0 / 9.0)


@_jit
def peaks(blobs, starts, xs, ys, image, level, sigma, keep):
    """The numpy ``_peaks``: significant local maxima of the 3x3-smoothed profile of each of the ``blobs`` (B,)
    (sorted ids); ``starts`` (N + 1,), ``xs``, ``ys`` (T,) all blobs' pixels as :func:`label_blobs` gives them; at
    most ``keep`` maxima per blob are compared. Returns blob (M,) (ids), x, y (M,) float64, by blob, highest
    first."""
    n = blobs.shape[0]
    total = 0
    for b in range(n):
        total += starts[blobs[b] + 1] - starts[blobs[b]]
    mb, mx, my = np.empty(total, np.int64), np.empty(total, np.int64), np.empty(total, np.int64)
    mv = np.empty(total, np.float32)
    first = np.empty(n + 1, np.int64)
    m = 0
    far = 0.0
    for b in range(n):
        first[b] = m
        for i in range(starts[blobs[b]], starts[blobs[b] + 1]):
            x, y = xs[i], ys[i]
            v = _smooth(image, x, y)
            top = True
            for dy in range(-1, 2):
                for dx in range(-1, 2):
                    if (dx != 0 or dy != 0) and _smooth(image, x + dx, y + dy) > v:
                        top = False
            if not top:
                continue
            at = m  # insert: highest first, ties in raster order (the pixels come in raster order)
            while at > first[b] and mv[at - 1] < v:
                mb[at], mx[at], my[at], mv[at] = mb[at - 1], mx[at - 1], my[at - 1], mv[at - 1]
                at -= 1
            mb[at], mx[at], my[at], mv[at] = blobs[b], x, y, v
            m += 1
        m = min(m, first[b] + keep)
        for i in range(first[b], m):
            for j in range(first[b], i):
                far = max(far, math.hypot(mx[i] - mx[j], my[i] - my[j]))
    first[n] = m
    n_steps = 2 * int(math.ceil(far))
    significant = np.ones(m, np.bool_)
    for b in range(n):
        for i in range(first[b], first[b + 1]):
            for j in range(first[b], i):
                dist = math.hypot(mx[i] - mx[j], my[i] - my[j])
                if dist < 2.0:
                    significant[i] = False
                    break
                lowest = np.float32(np.inf)
                for k in range(n_steps + 1):
                    step = k / n_steps
                    lowest = min(lowest, _smooth(image, int(np.rint(mx[i] + (mx[j] - mx[i]) * step)),
                                                 int(np.rint(my[i] + (my[j] - my[i]) * step))))
                pv_i, pv_j = np.float64(mv[i]), np.float64(mv[j])
                if min(pv_i, pv_j) - np.float64(lowest) <= max(4.0 * sigma, 0.1 * (pv_i - level)):
                    significant[i] = False
                    break
    keep_out = np.flatnonzero(significant)
    return mb[keep_out], mx[keep_out].astype(np.float64), my[keep_out].astype(np.float64)


# ---------------------------------------------------------------------------------------------- fit windows
@_jit
def window(origin, centre, radius, count, all_ox, all_oy, image, labels, base, bx0, by0, width, height, local, own, t,
           level, saturated):
    """The numpy ``_window``'s usable pixels: of the first ``count`` (N,) offsets ``all_ox``, ``all_oy`` around each
    ``origin`` (N, 2) int, those on the image, within ``radius`` (N,) of ``centre`` (N, 2), not ``saturated`` and,
    brighter than ``t``, owned by blob ``own`` (N,) (``labels`` ... ``local``: ``mocap.detect._Owners``).

    Returns:
        seg (T,) int64, ox, oy (T,) float32 offsets from the origin, values (T,) float32 grey minus ``level``.
    """
    h, w = image.shape
    n = origin.shape[0]
    total = 0
    for b in range(n):
        total += count[b]
    seg = np.empty(total, np.int64)
    ox = np.empty(total, np.float32)
    oy = np.empty(total, np.float32)
    values = np.empty(total, np.float32)
    lvl = np.float32(level)
    end = 0
    for b in range(n):
        x0, y0 = origin[b, 0], origin[b, 1]
        fx, fy = centre[b, 0] - x0, centre[b, 1] - y0
        r2 = radius[b] * radius[b]
        blob = own[b]
        for i in range(count[b]):
            x, y = x0 + all_ox[i], y0 + all_oy[i]
            if x < 0 or y < 0 or x >= w or y >= h:
                continue
            dx, dy = all_ox[i] - fx, all_oy[i] - fy
            grey = image[y, x]
            if dx * dx + dy * dy > r2 or grey >= saturated:
                continue
            if grey > t:  # another blob's pixel?
                rx, ry = x - bx0[blob], y - by0[blob]
                if (rx < 0 or ry < 0 or rx >= width[blob] or ry >= height[blob]
                        or labels[base[blob] + ry * width[blob] + rx] != local[blob]):
                    continue
            seg[end] = b
            ox[end], oy[end] = all_ox[i], all_oy[i]
            values[end] = np.float32(grey) - lvl
            end += 1
    return seg[:end], ox[:end], oy[:end], values[:end]


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
def _disc_terms(dx, dy, amp, r, s, tables, steps, half, z_res, z_origin, z_last, min_footprint):
    """One blurred disc at a pixel (dx, dy) px from its centre: its edge profile ``f`` and the derivatives of
    ``amp * f`` by the centre's x and y, the radius ``r`` and the blur ``s`` (the tables as :func:`fit_discs`'s)."""
    rho = math.sqrt(dx * dx + dy * dy)
    inv_rho = 1.0 / max(rho, 1e-6)
    a = max(abs(dx) * inv_rho, min_footprint)  # the pixel's footprint across the edge
    bb = max(abs(dy) * inv_rho, min_footprint)
    inv_s = 1.0 / s
    depth = r - rho
    inside = depth > 0.0
    offset = half if inside else 0
    centre = depth * (z_res * inv_s) + z_origin
    half_sum, half_diff = (a + bb) * (0.5 * z_res * inv_s), abs(a - bb) * (0.5 * z_res * inv_s)
    z0 = min(max(centre + half_sum, 0.0), z_last)  # the four corners of the footprint, as table positions
    z1 = min(max(centre + half_diff, 0.0), z_last)
    z2 = min(max(centre - half_diff, 0.0), z_last)
    z3 = min(max(centre - half_sum, 0.0), z_last)
    c0, c1, c2, c3 = int(z0), int(z1), int(z2), int(z3)  # (z >= 0: the floor)
    d0, d1, d2, d3 = steps[c0 + offset], steps[c1 + offset], steps[c2 + offset], steps[c3 + offset]
    sum_t = ((tables[c0 + offset] + (z0 - c0) * d0) + (tables[c3 + offset] + (z3 - c3) * d3)) - (
        (tables[c1 + offset] + (z1 - c1) * d1) + (tables[c2 + offset] + (z2 - c2) * d2))
    zt = ((z0 - z_origin) * d0 + (z3 - z_origin) * d3) - ((z1 - z_origin) * d1 + (z2 - z_origin) * d2)  # z T'(z)
    scale = s / (a * bb)
    f = sum_t * scale * s + (1.0 if inside else 0.0)
    slope = ((d0 + d3) - (d1 + d2)) * (scale * z_res) * amp
    return f, slope * inv_rho * dx, slope * inv_rho * dy, slope, amp * scale * (2.0 * sum_t - zt)


@_jit
def _normal_equations_one_disc(values, ox, oy, first, end, params, tables, steps, half, z_res, z_origin, z_last,
                               min_footprint, jtj, grad):
    """``jtj`` (6, 6) and ``grad`` (6,) of one blob fitted as one disc (its pixels ``first`` to ``end``, ``params``
    (6,)): :func:`fit_discs`'s sums with every entry in a register. Returns the residuals' sum of squares."""
    b0, cx, cy, amp, r, s = params[0], params[1], params[2], params[3], params[4], params[5]
    g0 = g1 = g2 = g3 = g4 = g5 = ss = 0.0
    a00 = a01 = a02 = a03 = a04 = a05 = a11 = a12 = a13 = a14 = a15 = 0.0
    a22 = a23 = a24 = a25 = a33 = a34 = a35 = a44 = a45 = a55 = 0.0
    for p in range(first, end):
        f, j1, j2, j4, j5 = _disc_terms(ox[p] - cx, oy[p] - cy, amp, r, s, tables, steps, half, z_res, z_origin,
                                        z_last, min_footprint)
        j3 = f
        resid = values[p] - (b0 + amp * f)
        ss += resid * resid
        g0 += resid
        g1 += j1 * resid
        g2 += j2 * resid
        g3 += j3 * resid
        g4 += j4 * resid
        g5 += j5 * resid
        a00 += 1.0
        a01 += j1
        a02 += j2
        a03 += j3
        a04 += j4
        a05 += j5
        a11 += j1 * j1
        a12 += j1 * j2
        a13 += j1 * j3
        a14 += j1 * j4
        a15 += j1 * j5
        a22 += j2 * j2
        a23 += j2 * j3
        a24 += j2 * j4
        a25 += j2 * j5
        a33 += j3 * j3
        a34 += j3 * j4
        a35 += j3 * j5
        a44 += j4 * j4
        a45 += j4 * j5
        a55 += j5 * j5
    grad[0], grad[1], grad[2], grad[3], grad[4], grad[5] = g0, g1, g2, g3, g4, g5
    jtj[0, 0], jtj[0, 1], jtj[0, 2], jtj[0, 3], jtj[0, 4], jtj[0, 5] = a00, a01, a02, a03, a04, a05
    jtj[1, 1], jtj[1, 2], jtj[1, 3], jtj[1, 4], jtj[1, 5] = a11, a12, a13, a14, a15
    jtj[2, 2], jtj[2, 3], jtj[2, 4], jtj[2, 5] = a22, a23, a24, a25
    jtj[3, 3], jtj[3, 4], jtj[3, 5] = a33, a34, a35
    jtj[4, 4], jtj[4, 5] = a44, a45
    jtj[5, 5] = a55
    return ss


@_jit
def fit_discs(values, ox, oy, starts, params, iterations, tables, steps, z_res, z_origin, z_last, min_footprint,
              damping, step_bound, low, high):
    """Detection's ``_fit_discs`` (:mod:`mocap.detect`), blob by blob, pixel by pixel, in float64 (the numpy one
    runs its pixel arithmetic in float32: centres agree to ~1e-6 px). ``starts`` (N + 1,): each blob's first pixel
    and the end; ``params`` (N, 1 + 5K) float64 starts, updated in place; the edge ``tables``/``steps`` and the
    bounds as in :mod:`mocap.detect`. Returns the unscaled covariance (N, 1 + 5K, 1 + 5K) of the last step and the
    residuals' sum of squares (N,) at its start."""
    n, n_par = params.shape
    n_discs = (n_par - 1) // 5
    half = tables.shape[0] // 2
    cov_out = np.empty((n, n_par, n_par))
    ss_out = np.empty(n)
    J = np.empty(n_par)
    jtj = np.empty((n_par, n_par))
    grad = np.empty(n_par)
    lhs, damped = np.empty((n_par, n_par)), np.empty((n_par, n_par))
    step, unit, column = np.empty(n_par), np.empty(n_par), np.empty(n_par)
    for b in range(n):
        for step_no in range(iterations):
            if n_discs == 1:
                ss = _normal_equations_one_disc(values, ox, oy, starts[b], starts[b + 1], params[b], tables, steps,
                                                half, z_res, z_origin, z_last, min_footprint, jtj, grad)
            else:
                jtj[:] = 0.0
                grad[:] = 0.0
                ss = 0.0
                for p in range(starts[b], starts[b + 1]):
                    model = params[b, 0]
                    J[0] = 1.0
                    for k in range(n_discs):
                        q = 1 + 5 * k
                        amp = params[b, q + 2]
                        f, J[q], J[q + 1], J[q + 3], J[q + 4] = _disc_terms(
                            ox[p] - params[b, q], oy[p] - params[b, q + 1], amp, params[b, q + 3],
                            params[b, q + 4], tables, steps, half, z_res, z_origin, z_last, min_footprint)
                        model += amp * f
                        J[q + 2] = f
                    resid = values[p] - model
                    ss += resid * resid
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
                ss_out[b] = ss
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
    return cov_out, ss_out


@_jit
def fit_results(params, pcov, start, origin, centroid_cov, sigma, k, vague_factor, pixel_var):
    """Centres (N, k, 2) px, covariances (N, k, 2, 2) px^2 and (N,) whether a disc's fit failed, from the fitted
    ``params`` and ``pcov`` (N, 2k, 2k) of :func:`fit_discs`, the ``start`` (N, 1 + 5k) it began from (centres
    relative to ``origin`` (N, 2)) and the blobs' centroid covariances (N, 2, 2), as :func:`mocap.detect._fit_results`
    checks them: a disc whose offset or covariance is not finite, whose covariance is not positive or exceeds
    ``vague_factor`` times the centroid's trace, or whose centre wandered more than max(1.5 px, its radius) falls
    back to its start with the centroid's covariance (+ ``pixel_var`` (N,) px^2 per axis for k = 1, 0.25 for k > 1)."""
    n = params.shape[0]
    centres = np.empty((n, k, 2))
    covs = np.empty((n, k, 2, 2))
    failed = np.zeros(n, np.bool_)
    s2 = sigma * sigma
    for i in range(n):
        extra = 0.25 if k > 1 else pixel_var[i]
        f00 = centroid_cov[i, 0, 0] * s2 + extra
        f01 = centroid_cov[i, 0, 1] * s2
        f10 = centroid_cov[i, 1, 0] * s2
        f11 = centroid_cov[i, 1, 1] * s2 + extra
        for j in range(k):
            p = 1 + 5 * j
            sx = start[i, p] + origin[i, 0]
            sy = start[i, p + 1] + origin[i, 1]
            dx = params[i, p] - start[i, p]
            dy = params[i, p + 1] - start[i, p + 1]
            a = pcov[i, 2 * j, 2 * j] * s2
            b = pcov[i, 2 * j, 2 * j + 1] * s2
            c = pcov[i, 2 * j + 1, 2 * j] * s2
            d = pcov[i, 2 * j + 1, 2 * j + 1] * s2
            finite = (math.isfinite(dx) and math.isfinite(dy) and math.isfinite(a) and math.isfinite(b)
                      and math.isfinite(c) and math.isfinite(d))
            vague = a < 0 or a * d < b * b or a + d > vague_factor * (f00 + f11)
            r = params[i, p + 3]
            reach = 1.5 if r <= 1.5 else r  # (np.maximum: a NaN radius stays NaN, and nothing exceeds it)
            bad = not finite or vague or math.hypot(dx, dy) > reach
            if bad:
                failed[i] = True
                centres[i, j, 0], centres[i, j, 1] = sx, sy
                covs[i, j, 0, 0], covs[i, j, 0, 1], covs[i, j, 1, 0], covs[i, j, 1, 1] = f00, f01, f10, f11
            else:
                centres[i, j, 0], centres[i, j, 1] = sx + dx, sy + dy
                covs[i, j, 0, 0], covs[i, j, 0, 1], covs[i, j, 1, 0], covs[i, j, 1, 1] = a, b, c, d
    return centres, covs, failed


# ---------------------------------------------------------------------------------------------- cut disc fit
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
_SQRT_HALF = math.sqrt(0.5)


@_jit
def _cut_disc_pixel(dx, dy, p, cos, sin, inv_s, J):
    """The cut disc's model (less its offset) at a pixel ``dx, dy`` px from the centre ``p[1:3]`` (``p`` (8,):
    :mod:`mocap.cutdisc`'s parameters; ``cos``, ``sin`` of its edge's normal, ``inv_s`` 1 / its blur); fills ``J``
    (8,) with its Jacobian unless ``J`` is empty."""
    amp, r, d = p[3], p[4], p[7]
    rho = math.sqrt(dx * dx + dy * dy)
    u, v = (r - rho) * inv_s, (d - (dx * cos + dy * sin)) * inv_s
    disc, cut = 0.5 * math.erfc(-u * _SQRT_HALF), 0.5 * math.erfc(-v * _SQRT_HALF)
    if J.shape[0]:
        disc_slope = math.exp(-0.5 * u * u) * _INV_SQRT_2PI * inv_s
        cut_slope = math.exp(-0.5 * v * v) * _INV_SQRT_2PI * inv_s
        radial = amp * disc_slope * cut / max(rho, 1e-9)
        edge = amp * disc * cut_slope
        J[0] = 1.0
        J[1] = radial * dx + edge * cos
        J[2] = radial * dy + edge * sin
        J[3] = disc * cut
        J[4] = amp * disc_slope * cut
        J[5] = -(amp * disc_slope * cut * u + edge * v)
        J[6] = edge * (dx * sin - dy * cos)
        J[7] = edge
    return amp * disc * cut


@_jit
def _cut_disc_sums(values, ox, oy, first, end, p, J, jtj, grad):
    """The residuals' sum of squares of one blob's pixels ``first`` to ``end`` under the cut disc ``p`` (8,); with a
    non-empty ``J`` also ``jtj`` (8, 8) and ``grad`` (8,)."""
    ss = 0.0
    if J.shape[0]:
        jtj[:] = 0.0
        grad[:] = 0.0
    cos, sin, inv_s = math.cos(p[6]), math.sin(p[6]), 1.0 / p[5]
    for q in range(first, end):
        resid = values[q] - p[0] - _cut_disc_pixel(ox[q] - p[1], oy[q] - p[2], p, cos, sin, inv_s, J)
        ss += resid * resid
        if J.shape[0]:
            for i in range(8):
                grad[i] += J[i] * resid
                for j in range(i, 8):
                    jtj[i, j] += J[i] * J[j]
    if J.shape[0]:
        for i in range(8):
            for j in range(i):
                jtj[i, j] = jtj[j, i]
    return ss


@_jit
def fit_cut_discs(values, ox, oy, starts, start_params, n_starts, iterations, low, high, bound):
    """:func:`mocap.cutdisc.fit_cut_discs` blob by blob: ``starts`` (N + 1,) each blob's first pixel and the end,
    ``start_params`` (N * n_starts, 8), the parameters' bounds ``low``, ``high`` and the step ``bound`` (8,). Returns
    the best start's parameters (N, 8), ``(J^T J)^-1`` (N, 8, 8; NaN where singular) and sums of squares (N,)."""
    n = starts.shape[0] - 1
    out = np.empty((n, 8))
    cov_out = np.full((n, 8, 8), np.nan)
    cost_out = np.empty(n)
    J, none = np.empty(8), np.empty(0)
    jtj, grad, lhs, best_jtj = np.empty((8, 8)), np.empty(8), np.empty((8, 8)), np.empty((8, 8))
    p, trial = np.empty(8), np.empty(8)
    for b in range(n):
        first, end = starts[b], starts[b + 1]
        best = np.inf
        out[b] = start_params[b * n_starts]
        best_jtj[:] = np.nan
        for k in range(n_starts):
            p[:] = start_params[b * n_starts + k]
            cost = _cut_disc_sums(values, ox, oy, first, end, p, J, jtj, grad)
            damping = 1e-2
            for _ in range(iterations):
                lhs[:] = jtj
                for i in range(8):
                    lhs[i, i] = jtj[i, i] * (1.0 + damping) + 1e-9
                step = np.linalg.solve(lhs, grad)
                for i in range(8):
                    trial[i] = min(max(p[i] + min(max(step[i], -bound[i]), bound[i]), low[i]), high[i])
                trial_cost = _cut_disc_sums(values, ox, oy, first, end, trial, none, jtj, grad)
                if trial_cost < cost:
                    p[:] = trial
                    cost = trial_cost
                    damping = max(damping / 3.0, 1e-6)
                    _cut_disc_sums(values, ox, oy, first, end, p, J, jtj, grad)
                else:
                    damping = min(damping * 4.0, 1e6)
            if cost < best:
                best = cost
                out[b] = p
                best_jtj[:] = jtj
        cost_out[b] = best if best < np.inf else np.nan
        if np.isfinite(best_jtj).all():
            singular = np.linalg.svd(best_jtj)[1]
            if singular[7] > 0.0 and singular[0] < 1e12 * singular[7]:
                cov_out[b] = np.linalg.inv(best_jtj)
    return out, cov_out, cost_out
