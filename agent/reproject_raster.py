"""The loops of :mod:`skelfuse.agent.reproject`: the projection of the source pixels into the
reference camera (:func:`project_loop`, its numpy twin is in that module) and the z-buffered
rasteriser (:func:`raster_loop` and its numpy twin :func:`raster_numpy`).

Both rasterisers draw the same image from the same inputs: the source pixels already projected
into the reference camera (``u``, ``v`` pixels, ``z`` metres along its axis, ``ir`` values)
and, per source pixel, whether it has a reading and its source depth (for the edge rule).

- Mesh: each 2×2 block of source pixels gives two triangles, drawn only when all three corners
  have readings and their source depths differ by less than ``max_edge_m`` (so person and
  background are never bridged). When neither is drawn (a corner on their shared diagonal is
  missing or across an edge), the other diagonal's two triangles are tried, so a block with three
  good corners still covers half its area. Depth is interpolated as 1/z (exact for a planar
  triangle under perspective), IR perspective-correctly. A pixel is inside when its centre is
  (edges included). Triangles spanning more than ``MAX_SPAN_PX`` pixels (grazing surfaces) are
  skipped.
- Dropouts: a source pixel without a reading is covered by the diamond of its four neighbours
  (two triangles split north–south, each under the same 10 cm rule), so a lone dropout inside a
  surface is filled from it instead of leaving a hole the size of its neighbourhood; on
  simulated 2 % dropout this took the re-projection's holes from 1.8–3.5 % to 0.5–1.3 % of the
  person's silhouette (docs/benchmarks.md).
- Points: every valid source pixel also lands on its nearest reference pixel; the mesh alone
  loses a half-pixel rim at every gap, the points give it back.
- Z-buffer: the nearest surface wins; missing = +inf depth.

numba is optional (the ``fast`` extra): looked up and configured by :mod:`skelfuse.jit`, which
the fusion kernels share (the agent may not import :mod:`skelfuse.fusion`).
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.jit import jit, numba_module

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

MAX_SPAN_PX: Final = 32
"""Triangles whose bounding box is wider or taller than this (pixels) are not drawn."""


@jit
def project_loop(
    depth: FloatArray,
    camera: FloatArray,
    transform: FloatArray,
    u: FloatArray,
    v: FloatArray,
    z: FloatArray,
    valid: BoolArray,
) -> None:
    """Source pixels into the reference camera, as the numpy code of
    :func:`skelfuse.agent.reproject.reproject_depth` does: ``depth`` (H, W) metres (cleaned in
    place: non-finite or ≤ 0 becomes 0), ``camera`` (fx, fy, cx, cy), ``transform`` (4, 4)
    ref-from-sensor; fills ``u``, ``v`` (pixels), ``z`` (metres, 1 where not valid) and
    ``valid`` (a reading in front of the reference camera)."""
    fx, fy, cx, cy = camera[0], camera[1], camera[2], camera[3]
    for row in range(depth.shape[0]):
        for col in range(depth.shape[1]):
            d = depth[row, col]
            if not (math.isfinite(d) and d > 0.0):
                depth[row, col] = d = 0.0
            x = -(col - cx) * d / fx
            y = -(row - cy) * d / fy
            xr = transform[0, 0] * x + transform[0, 1] * y + transform[0, 2] * d + transform[0, 3]
            yr = transform[1, 0] * x + transform[1, 1] * y + transform[1, 2] * d + transform[1, 3]
            zr = transform[2, 0] * x + transform[2, 1] * y + transform[2, 2] * d + transform[2, 3]
            ok = d > 0.0 and zr > 1e-3
            valid[row, col] = ok
            if ok:
                z[row, col] = zr
                u[row, col] = cx - fx * xr / zr
                v[row, col] = cy - fy * yr / zr
            else:
                z[row, col], u[row, col], v[row, col] = 1.0, 0.0, 0.0


@jit
def raster_loop(
    u: FloatArray,
    v: FloatArray,
    z: FloatArray,
    ir: FloatArray,
    valid: BoolArray,
    source_z: FloatArray,
    max_edge_m: float,
    out_z: FloatArray,
    out_ir: FloatArray,
) -> None:
    """Draw mesh and points into ``out_z`` / ``out_ir`` (reference H', W'; ``out_z`` filled
    with +inf by the caller). Inputs are (H, W) per source pixel; ``valid`` also requires the
    point to be in front of the reference camera; ``source_z`` is 0 where the sensor gave no
    reading."""
    height, width = u.shape
    out_h, out_w = out_z.shape
    for row in range(height - 1):
        for col in range(width - 1):
            split_joined = False
            for tri in range(6):
                # The block's corners: top-left (row, col) to bottom-right (row + 1, col + 1).
                if tri == 0:  # its usual split: top-left, then bottom-right triangle
                    r0, c0, r1, c1, r2, c2 = row, col, row, col + 1, row + 1, col
                elif tri == 1:
                    r0, c0, r1, c1, r2, c2 = row, col + 1, row + 1, col + 1, row + 1, col
                elif tri < 4:
                    # Neither joined: a corner on that diagonal is missing or across an edge;
                    # the other diagonal's triangles keep the three corners left.
                    if split_joined:
                        continue
                    if tri == 2:
                        r0, c0, r1, c1, r2, c2 = row, col, row, col + 1, row + 1, col + 1
                    else:
                        r0, c0, r1, c1, r2, c2 = row, col, row + 1, col + 1, row + 1, col
                else:
                    # A dropped pixel (no reading) at the block's top-left: the diamond of its
                    # four neighbours, split north-south, covers it.
                    if row == 0 or col == 0 or source_z[row, col] != 0.0:
                        break
                    if tri == 4:
                        r0, c0, r1, c1, r2, c2 = row - 1, col, row, col + 1, row + 1, col
                    else:
                        r0, c0, r1, c1, r2, c2 = row - 1, col, row + 1, col, row, col - 1
                if not (valid[r0, c0] and valid[r1, c1] and valid[r2, c2]):
                    continue
                s0, s1, s2 = source_z[r0, c0], source_z[r1, c1], source_z[r2, c2]
                if max(s0, s1, s2) - min(s0, s1, s2) >= max_edge_m:
                    continue
                if tri < 2:
                    split_joined = True
                x0, y0, x1, y1, x2, y2 = (
                    u[r0, c0],
                    v[r0, c0],
                    u[r1, c1],
                    v[r1, c1],
                    u[r2, c2],
                    v[r2, c2],
                )
                lo_x = math.ceil(min(x0, x1, x2))
                hi_x = math.floor(max(x0, x1, x2))
                lo_y = math.ceil(min(y0, y1, y2))
                hi_y = math.floor(max(y0, y1, y2))
                if hi_x - lo_x > MAX_SPAN_PX or hi_y - lo_y > MAX_SPAN_PX:
                    continue
                area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
                if area == 0.0:
                    continue
                q0, q1, q2 = 1.0 / z[r0, c0], 1.0 / z[r1, c1], 1.0 / z[r2, c2]
                i0, i1, i2 = ir[r0, c0] * q0, ir[r1, c1] * q1, ir[r2, c2] * q2
                for py in range(max(lo_y, 0), min(hi_y, out_h - 1) + 1):
                    for px in range(max(lo_x, 0), min(hi_x, out_w - 1) + 1):
                        w1 = ((px - x0) * (y2 - y0) - (x2 - x0) * (py - y0)) / area
                        w2 = ((x1 - x0) * (py - y0) - (px - x0) * (y1 - y0)) / area
                        w0 = 1.0 - w1 - w2
                        if w0 < -1e-9 or w1 < -1e-9 or w2 < -1e-9:
                            continue
                        inv_z = w0 * q0 + w1 * q1 + w2 * q2
                        depth = 1.0 / inv_z
                        if depth < out_z[py, px]:
                            out_z[py, px] = depth
                            out_ir[py, px] = (w0 * i0 + w1 * i1 + w2 * i2) / inv_z
    for row in range(height):
        for col in range(width):
            if not valid[row, col]:
                continue
            px = math.floor(u[row, col] + 0.5)
            py = math.floor(v[row, col] + 0.5)
            if px < 0 or py < 0 or px >= out_w or py >= out_h:
                continue
            if z[row, col] < out_z[py, px]:
                out_z[py, px] = z[row, col]
                out_ir[py, px] = ir[row, col]


def raster_numpy(
    u: FloatArray,
    v: FloatArray,
    z: FloatArray,
    ir: FloatArray,
    valid: BoolArray,
    source_z: FloatArray,
    max_edge_m: float,
    out_z: FloatArray,
    out_ir: FloatArray,
) -> None:
    """:func:`raster_loop` with numpy arrays: every triangle at once, one pass per pixel offset
    within the triangles' bounding boxes (slower, for machines without numba)."""
    out_h, out_w = out_z.shape
    cand_idx: list[npt.NDArray[np.int64]] = []
    cand_z: list[FloatArray] = []
    cand_ir: list[FloatArray] = []
    triangles = _mesh_triangles(valid, source_z, max_edge_m)
    for tri, ok in triangles:
        x = np.stack([u[c][ok] for c in tri])
        y = np.stack([v[c][ok] for c in tri])
        q = 1.0 / np.stack([z[c][ok] for c in tri])
        iq = np.stack([ir[c][ok] for c in tri]) * q
        lo_x, hi_x = np.ceil(x.min(axis=0)), np.floor(x.max(axis=0))
        lo_y, hi_y = np.ceil(y.min(axis=0)), np.floor(y.max(axis=0))
        area = (x[1] - x[0]) * (y[2] - y[0]) - (x[2] - x[0]) * (y[1] - y[0])
        keep = (hi_x - lo_x <= MAX_SPAN_PX) & (hi_y - lo_y <= MAX_SPAN_PX) & (area != 0.0)
        # Clip the boxes to the image, as the loop does.
        lo_x, hi_x = np.maximum(lo_x, 0), np.minimum(hi_x, out_w - 1)
        lo_y, hi_y = np.maximum(lo_y, 0), np.minimum(hi_y, out_h - 1)
        keep &= (hi_x >= lo_x) & (hi_y >= lo_y)
        x, y, q, iq = x[:, keep], y[:, keep], q[:, keep], iq[:, keep]
        lo_x, hi_x, lo_y, hi_y, area = lo_x[keep], hi_x[keep], lo_y[keep], hi_y[keep], area[keep]
        span_x = int((hi_x - lo_x).max(initial=-1)) + 1
        span_y = int((hi_y - lo_y).max(initial=-1)) + 1
        for dy in range(span_y):
            for dx in range(span_x):
                px, py = lo_x + dx, lo_y + dy
                sel = np.flatnonzero((px <= hi_x) & (py <= hi_y))
                if sel.size == 0:
                    continue
                px, py = px[sel], py[sel]
                xs, ys, a = x[:, sel], y[:, sel], area[sel]
                w1 = ((px - xs[0]) * (ys[2] - ys[0]) - (xs[2] - xs[0]) * (py - ys[0])) / a
                w2 = ((xs[1] - xs[0]) * (py - ys[0]) - (px - xs[0]) * (ys[1] - ys[0])) / a
                w0 = 1.0 - w1 - w2
                inside = (w0 >= -1e-9) & (w1 >= -1e-9) & (w2 >= -1e-9)
                qs, iqs = q[:, sel], iq[:, sel]
                inv_z = w0 * qs[0] + w1 * qs[1] + w2 * qs[2]
                num = w0 * iqs[0] + w1 * iqs[1] + w2 * iqs[2]
                cand_idx.append((py[inside] * out_w + px[inside]).astype(np.int64))
                cand_z.append(1.0 / inv_z[inside])
                cand_ir.append(num[inside] / inv_z[inside])
    px_pt = np.floor(u + 0.5)
    py_pt = np.floor(v + 0.5)
    on = valid & (px_pt >= 0) & (py_pt >= 0) & (px_pt < out_w) & (py_pt < out_h)
    cand_idx.append((py_pt[on] * out_w + px_pt[on]).astype(np.int64))
    cand_z.append(z[on])
    cand_ir.append(ir[on])
    _keep_nearest(
        np.concatenate(cand_idx), np.concatenate(cand_z), np.concatenate(cand_ir), out_z, out_ir
    )


_Triangle = tuple[tuple[slice, slice], ...]
"""A triangle's three corners, each a 2-D slice of the (H, W) source grid."""


def _mesh_triangles(
    valid: BoolArray, source_z: FloatArray, max_edge_m: float
) -> list[tuple[_Triangle, BoolArray]]:
    """The mesh's triangles as :func:`raster_loop` picks them: each kind of triangle with the
    blocks where it is drawn (the block's usual split, else the other diagonal's halves, and
    the diamond over a dropped pixel)."""
    top_left, top_right = (slice(None, -1), slice(None, -1)), (slice(None, -1), slice(1, None))
    bottom_left, bottom_right = (slice(1, None), slice(None, -1)), (slice(1, None), slice(1, None))
    top = _joined_blocks((top_left, top_right, bottom_left), valid, source_z, max_edge_m)
    bottom = _joined_blocks((top_right, bottom_right, bottom_left), valid, source_z, max_edge_m)
    neither = ~(top | bottom)
    north, south = (slice(None, -2), slice(1, -1)), (slice(2, None), slice(1, -1))
    west, east = (slice(1, -1), slice(None, -2)), (slice(1, -1), slice(2, None))
    dropped = source_z[1:-1, 1:-1] == 0.0
    triangles: list[tuple[_Triangle, BoolArray]] = [
        ((top_left, top_right, bottom_left), top),
        ((top_right, bottom_right, bottom_left), bottom),
    ]
    for other in ((top_left, top_right, bottom_right), (top_left, bottom_right, bottom_left)):
        triangles.append((other, _joined_blocks(other, valid, source_z, max_edge_m) & neither))
    for half in ((north, east, south), (north, south, west)):
        triangles.append((half, _joined_blocks(half, valid, source_z, max_edge_m) & dropped))
    return triangles


def _keep_nearest(
    idx: npt.NDArray[np.int64],
    depth: FloatArray,
    values: FloatArray,
    out_z: FloatArray,
    out_ir: FloatArray,
) -> None:
    """Write the nearest candidate of each pixel (flat index ``idx`` into the reference image,
    ``depth`` metres, IR ``values``) where it is nearer than what ``out_z`` holds."""
    order = np.lexsort((depth, idx))
    idx, depth, values = idx[order], depth[order], values[order]
    first = np.ones(idx.size, dtype=bool)
    first[1:] = idx[1:] != idx[:-1]
    flat_z = out_z.reshape(-1)
    flat_ir = out_ir.reshape(-1)
    winners = idx[first]
    nearer = depth[first] < flat_z[winners]
    flat_z[winners[nearer]] = depth[first][nearer]
    flat_ir[winners[nearer]] = values[first][nearer]


def _joined_blocks(
    tri: tuple[tuple[slice, slice], ...], valid: BoolArray, source_z: FloatArray, max_edge_m: float
) -> BoolArray:
    """Per block (or pixel), whether a triangle is joined: its three corners, ``tri``, given as
    views of the source image, all have readings within ``max_edge_m`` of each other."""
    ok = valid[tri[0]] & valid[tri[1]] & valid[tri[2]]
    s = np.stack([source_z[c] for c in tri])
    joined: BoolArray = ok & ((s.max(axis=0) - s.min(axis=0)) < max_edge_m)
    return joined


def warm_up() -> None:
    """Compile :func:`raster_loop` (or load it from numba's disk cache) on a 2×2 image, so the
    first frame does not wait ~1 s for it; nothing to do without numba."""
    if numba_module() is None:
        return
    out = np.zeros((2, 2))
    project_loop(
        np.ones((2, 2)),
        np.ones(4),
        np.eye(4),
        out,
        out.copy(),
        out.copy(),
        np.zeros((2, 2), dtype=bool),
    )
    grid = np.array([[0.0, 1.0], [0.0, 1.0]])
    ones = np.ones((2, 2))
    raster_loop(
        grid,
        grid.T.copy(),
        ones,
        ones,
        np.ones((2, 2), dtype=bool),
        ones,
        0.1,
        np.full((2, 2), np.inf),
        np.zeros((2, 2)),
    )
