"""Footprint and view statistics of a view (map CRS; areas and ranges in true metres)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import shapely
import shapely.affinity

from mars_pairs.pipeline.sample.view import View

Spans = tuple[np.ndarray, np.ndarray, np.ndarray]  # row_spans: rows, first and last columns


def row_spans(mask: np.ndarray) -> Spans:
    """The rows of ``mask`` with a set cell, and each one's first and last set column."""
    rows = np.flatnonzero(mask.any(axis=1))
    sub = mask[rows]
    first = np.argmax(sub, axis=1)
    last = sub.shape[1] - 1 - np.argmax(sub[:, ::-1], axis=1)
    return rows, first, last


def footprint_polygon(view: View, spans: Spans | None = None) -> shapely.Polygon | None:
    """Convex hull of the visible cells (their corners) and the camera position, map CRS.
    ``spans``: ``row_spans(view.mask)`` when the caller has it."""
    rows, first, last = row_spans(view.mask) if spans is None else spans
    if len(rows) == 0:
        return None
    cols = np.concatenate([first - 0.5, last + 0.5, first - 0.5, last + 0.5])
    rr = np.concatenate([rows - 0.5, rows - 0.5, rows + 0.5, rows + 0.5])
    x, y = view.window.colrow_to_xy(cols, rr)
    centre = view.camera.center_map
    points = shapely.multipoints(
        np.column_stack([np.append(x, centre[0]), np.append(y, centre[1])])
    )
    assert isinstance(points, shapely.MultiPoint)  # (N, 2) coordinates: one geometry
    hull = shapely.convex_hull(points)
    return hull if isinstance(hull, shapely.Polygon) else hull.buffer(0.5)


def view_statistics(view: View, spans: Spans | None = None) -> dict[str, Any]:
    """Visible cell count, area (true m2) and farthest visible range (m), ray hit fraction.
    ``spans``: ``row_spans(view.mask)`` when the caller has it."""
    visible = int(np.count_nonzero(view.mask))
    cam = view.camera
    # map units -> true metres through the local Jacobian (scale factors, R / (R + h))
    area_scale = 1.0 / abs(float(np.linalg.det(cam.jacobian[:2, :2])))
    cell_area = abs(view.window.transform.a * view.window.transform.e)
    max_range = 0.0
    if visible:
        # map_to_local is affine, so distance from the camera is convex along a row and the
        # farthest visible cell of a row is one of its visible span's two ends: exact
        rows, first, last = row_spans(view.mask) if spans is None else spans
        x, y = view.window.colrow_to_xy(np.concatenate([first, last]), np.tile(rows, 2))
        local = cam.map_to_local(np.column_stack([x, y, np.full_like(x, cam.center_map[2])]))
        centre = cam.map_to_local(cam.center_map)
        max_range = float(np.hypot(local[:, 0] - centre[0], local[:, 1] - centre[1]).max())
    hit_fraction = None
    if view.hits is not None:
        hit_fraction = float(np.isfinite(view.hits[:, 0]).mean())
    return {
        "visible_cells": visible,
        "viewshed_area_m2": float(visible * cell_area * area_scale),
        "max_visible_range_m": max_range,
        "ray_hit_fraction": hit_fraction,
    }


# ---- the visible footprint as a polygon: line of sight per DEM cell, the view test's edge
# ---- traced (sub-cell lattice, crossings refined by root finding) -------------------------

#: how far simplification may move the outline, as a fraction of the DEM cell (5 mm on a 1 m
#: DEM): the traced edge lies within a few mm of the view test's edge, and a view of a few
#: square metres (a targeted frame at the rover's feet) meets its chip at IoU >= 0.95 only
#: with its edges kept to a few mm; the cells' staircase along the line of sight's edge
#: keeps its corners at any tolerance below half a cell
SIMPLIFY_CELLS = 0.005
#: the view test's edge is traced on a lattice of 1 / s of the DEM cell: chords between exact
#: crossings of the lattice's lines sag by ~h^2 / (8 d) at range d (h = 1 / s cells), so a
#: view whose nearest cell in view is near the camera takes a finer lattice (``lattice_of``)
_SAG_M = 0.002
_MAX_SUB = 8
_LATTICE_CELLS = 24.0
_ROOT_STEPS = (4, 6)  # bisection steps, then regula falsi (Illinois) steps, per crossing
_NEWTON_STEPS = 4  # per image corner, from the middle of the chord it cuts


def bilinear(data: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """``data`` (rows, cols; cell centres at integers) at fractional (col, row), bilinear,
    clamped at the edges; NaN where a neighbour is NaN (as the chips' DEM reads)."""
    h, w = data.shape
    c = np.clip(col, 0.0, w - 1.0)
    r = np.clip(row, 0.0, h - 1.0)
    c0 = np.minimum(np.floor(c).astype(np.intp), max(w - 2, 0))
    r0 = np.minimum(np.floor(r).astype(np.intp), max(h - 2, 0))
    c1, r1 = np.minimum(c0 + 1, w - 1), np.minimum(r0 + 1, h - 1)
    fc, fr = c - c0, r - r0
    d = data.astype(np.float64, copy=False)
    top = d[r0, c0] * (1 - fc) + d[r0, c1] * fc
    bottom = d[r1, c0] * (1 - fc) + d[r1, c1] * fc
    out: np.ndarray = top * (1 - fr) + bottom * fr
    return out


def view_terms(view: View, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """The terms of the view's exact test (``in_view``'s) at window points (fractional col,
    row; cell centres at integers) on the DEM's bilinear surface, (5, N), each >= 0 where its
    condition holds and 0 on its edge: the range margin (true metres), then frustum: the
    pixel distances to the image's left, right, top and bottom edges (-0.5 .. size - 0.5);
    band: the elevation margins to the band's lower and upper edges and the azimuth margin
    (degrees; +inf for a full circle and the unused term). -1e9 behind the camera or over no
    data."""
    from mars_pairs.geometry.body import MARS_RADIUS_M
    from mars_pairs.geometry.frames import azimuth_elevation_deg

    x, y = view.window.colrow_to_xy(col, row)
    z = bilinear(view.window.data, col, row)
    cam = view.camera
    local = cam.local_points(np.column_stack([x, y, z]), MARS_RADIUS_M)
    rel = local - cam.map_to_local(cam.center_map)
    terms = np.full((5, len(x)), np.inf)
    terms[0] = view.radius_m - np.hypot(rel[:, 0], rel[:, 1])
    if view.mode == "frustum":
        px = cam.camera.project(local)
        u, v = px[:, 0], px[:, 1]
        terms[1:] = [u + 0.5, cam.width - 0.5 - u, v + 0.5, cam.height - 0.5 - v]
    else:
        (az0, az1), (el0, el1) = view.bands
        az, el = azimuth_elevation_deg(rel)
        terms[1], terms[2] = el - el0, el1 - el
        if (az0, az1) != (0.0, 360.0):
            width = (az1 - az0) % 360.0
            terms[3] = width / 2.0 - np.abs((az - az0 - width / 2.0 + 180.0) % 360.0 - 180.0)
    out: np.ndarray = np.where(np.isnan(terms), -1e9, terms)
    return out


def view_margin(view: View, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """The least of ``view_terms``: continuous, >= 0 exactly where ``in_view`` keeps the
    point (window col, row on the DEM's bilinear surface), 0 on the test's edge."""
    out: np.ndarray = view_terms(view, col, row).min(axis=0)
    return out


def lattice_of(view: View) -> int:
    """Sub-cells per DEM cell side on which ``footprint_outline`` traces the view test's
    edge: the least s (1 .. 8) whose chord sag h^2 / (8 d) (h = cell / s metres, d the range
    of the nearest cell in view) stays within 2 mm, and at most ``_LATTICE_CELLS`` / sqrt(N)
    for a view of N cells (a chord's sag matters to a view of a few cells; a large view's
    edges are long against it, and its lattice stays small)."""
    rows, cols = np.nonzero(view.mask)
    if not len(rows):
        return 1
    x, y = view.window.colrow_to_xy(cols, rows)
    cam = view.camera
    near = np.hypot(x - cam.center_map[0], y - cam.center_map[1]).min()
    cell = float(max(abs(view.window.transform.a), abs(view.window.transform.e)))
    d = max(float(near) - cell, 0.25 * cell)
    h = math.sqrt(8.0 * d * _SAG_M)
    cap = max(int(_LATTICE_CELLS / math.sqrt(len(rows))), 1)
    return int(min(max(math.ceil(cell / h), 1), _MAX_SUB, cap))


def _crossings(view: View, col0: np.ndarray, row0: np.ndarray, dcol: np.ndarray,
               drow: np.ndarray) -> np.ndarray:  # fmt: skip
    """Where the margin changes sign on each lattice edge from (col0, row0) to (col0 + dcol,
    row0 + drow) (its ends on either side of the view test's edge): the fraction t in
    (0, 1) along it. The margins at both ends first, then bisection steps, then regula
    falsi with the Illinois rule, bisecting where an end has no margin (-1e9: behind the
    camera or over no data)."""
    n = len(col0)
    ends = view_margin(
        view, np.concatenate([col0, col0 + dcol]), np.concatenate([row0, row0 + drow])
    )
    lo, hi = np.zeros(n), np.ones(n)
    mlo, mhi = ends[:n], ends[n:]
    bisect, falsi = _ROOT_STEPS
    for step in range(bisect + falsi):
        t = 0.5 * (lo + hi)
        if step >= bisect:
            with np.errstate(divide="ignore", invalid="ignore"):
                rf = (lo * mhi - hi * mlo) / (mhi - mlo)
            usable = np.isfinite(rf) & (rf > lo) & (rf < hi) & (np.minimum(mlo, mhi) > -1e8)
            t = np.where(usable, rf, t)
        m = view_margin(view, col0 + t * dcol, row0 + t * drow)
        same = (m >= 0) == (mlo >= 0)
        if step >= bisect:  # Illinois: halve the end kept twice in a row
            mhi = np.where(same, mhi * 0.5, mhi)
            mlo = np.where(same, mlo, mlo * 0.5)
        lo, mlo = np.where(same, t, lo), np.where(same, m, mlo)
        hi, mhi = np.where(same, hi, t), np.where(same, mhi, m)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (lo * mhi - hi * mlo) / (mhi - mlo)
    ok = np.isfinite(t) & (t >= lo) & (t <= hi) & (np.minimum(mlo, mhi) > -1e8)
    out: np.ndarray = np.where(ok, t, 0.5 * (lo + hi))
    return out


#: marching squares: node bits (1 top-left, 2 top-right, 4 bottom-right, 8 bottom-left; set
#: = in view) -> the pairs of cell sides (0 top, 1 right, 2 bottom, 3 left) each contour
#: segment joins; the two saddles keep the cells in view apart
_CASES: dict[int, tuple[tuple[int, int], ...]] = {
    1: ((3, 0),), 2: ((0, 1),), 3: ((3, 1),), 4: ((1, 2),), 5: ((3, 0), (1, 2)),
    6: ((0, 2),), 7: ((3, 2),), 8: ((2, 3),), 9: ((2, 0),), 10: ((0, 1), (2, 3)),
    11: ((2, 1),), 12: ((1, 3),), 13: ((1, 0),), 14: ((0, 3),),
}  # fmt: skip


def footprint_outline(view: View) -> shapely.Polygon | shapely.MultiPolygon | None:
    """The visible footprint (map CRS): the DEM cells in line of sight (``view.los``, one
    verdict per cell, as a chip pixel takes its cell's) cut by the edge of the exact view
    test (``view_margin`` >= 0 on the DEM's bilinear surface, as ``chips.chip_view`` tests a
    chip pixel). The edge is traced on a lattice of 1 / ``lattice_of(view)`` cell over the
    cells in line of sight beside a cell in view (marching squares, each crossing of a
    lattice line found by root finding: on the demo all but 5 of 56,822 within 1 mm of
    the converged root); cells in line of sight whose corners and centre all pass are
    whole. Simplified (topology kept) by ``SIMPLIFY_CELLS`` of the DEM
    cell. None when nothing is in view. A sliver of the view narrower than a cell that holds
    no cell centre nor lattice node in view, away from every cell in view, is not drawn."""
    los = view.los.astype(bool)
    mask = view.mask.astype(bool)
    found = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if not len(found[0]):
        return None
    # the cells that can hold the footprint: in line of sight, beside a cell in view
    r0, c0 = max(int(found[0][0]) - 1, 0), max(int(found[1][0]) - 1, 0)
    r1 = min(int(found[0][-1]) + 2, los.shape[0])
    c1 = min(int(found[1][-1]) + 2, los.shape[1])
    cand = los[r0:r1, c0:c1] & _dilate(mask[r0:r1, c0:c1])
    centre = mask[r0:r1, c0:c1]
    s = lattice_of(view)
    h, w = cand.shape
    # the view test at the corners of the candidate cells (window edge coordinates: a cell
    # (r, c) spans columns c .. c + 1; bilinear centres at integers + 0.5)
    corner = np.zeros((h + 1, w + 1), dtype=bool)
    for dr in (0, 1):
        for dc in (0, 1):
            corner[dr : dr + h, dc : dc + w] |= cand
    cr, cc = np.nonzero(corner)
    cpass = np.zeros_like(corner)
    cpass[cr, cc] = view_margin(view, cc + c0 - 0.5, cr + r0 - 0.5) >= 0
    quad = [cpass[:-1, :-1], cpass[:-1, 1:], cpass[1:, 1:], cpass[1:, :-1]]
    full = cand & centre & quad[0] & quad[1] & quad[2] & quad[3]
    # the cells the test's edge may cross: those with a corner or centre in view that are
    # not whole, and their neighbours (a narrow view crosses cells through their sides)
    touched = cand & (centre | quad[0] | quad[1] | quad[2] | quad[3])
    mixed = cand & ~full & _dilate(touched & ~full)
    # the fine lattice: nodes of the whole cells in view, then the mixed cells' own nodes
    fine = np.repeat(np.repeat(cand, s, axis=0), s, axis=1)
    node = np.zeros((h * s + 1, w * s + 1), dtype=bool)
    fr, fc = np.nonzero(np.repeat(np.repeat(full, s, axis=0), s, axis=1))
    for dr in (0, 1):
        for dc in (0, 1):
            node[fr + dr, fc + dc] = True
    need = np.zeros_like(node)
    mr, mc = np.nonzero(np.repeat(np.repeat(mixed, s, axis=0), s, axis=1))
    for dr in (0, 1):
        for dc in (0, 1):
            need[mr + dr, mc + dc] = True
    nr, nc = np.nonzero(need)
    margin = np.zeros(node.shape)
    margin[node] = 1.0
    margin[nr, nc] = view_margin(view, nc / s + c0 - 0.5, nr / s + r0 - 0.5)
    node[nr, nc] = margin[nr, nc] >= 0
    segments = _outline_segments(view, node, margin, fine, s, c0, r0)
    if not segments:
        return None
    seg = np.concatenate(segments)
    seg = seg[np.any(seg[:, 0] != seg[:, 1], axis=1)]
    lines = shapely.linestrings(seg)
    faces = shapely.get_parts(shapely.polygonize(np.asarray(lines, dtype=object)))
    if not len(faces):
        return None
    # each face is a patch of the footprint or a hole in it: its representative point says
    inner = shapely.get_coordinates(shapely.point_on_surface(faces))
    fi, fj = np.floor(inner[:, 1]).astype(int), np.floor(inner[:, 0]).astype(int)
    ok = (fi >= 0) & (fj >= 0) & (fi < fine.shape[0]) & (fj < fine.shape[1])
    keep = np.zeros(len(faces), dtype=bool)
    keep[ok] = fine[fi[ok], fj[ok]]
    col, row = inner[keep, 0] / s + c0 - 0.5, inner[keep, 1] / s + r0 - 0.5
    keep[keep] = view_margin(view, col, row) >= 0
    if not keep.any():
        return None
    shape = shapely.union_all(faces[keep]) if keep.sum() > 1 else faces[keep][0]
    # lattice -> window edge coordinates -> map
    t = view.window.transform
    a, b, xoff = t.a / s, t.b / s, t.a * c0 + t.b * r0 + t.c
    d, e, yoff = t.d / s, t.e / s, t.d * c0 + t.e * r0 + t.f
    shape = shapely.affinity.affine_transform(shape, [a, b, d, e, xoff, yoff])
    cell = float(max(abs(t.a), abs(t.e)))
    simple = shapely.simplify(shape, SIMPLIFY_CELLS * cell, preserve_topology=True)
    if not simple.is_valid:
        simple = shapely.make_valid(simple)
    parts = [
        g for g in shapely.get_parts(simple) if isinstance(g, shapely.Polygon) and not g.is_empty
    ]
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)


def _dilate(mask: np.ndarray) -> np.ndarray:
    """Whether each cell's 3 x 3 neighbourhood in ``mask`` holds a set cell."""
    padded = np.pad(mask, 1)
    h, w = mask.shape
    out: np.ndarray = np.logical_or.reduce(
        [padded[i : i + h, j : j + w] for i in range(3) for j in range(3)]
    )
    return out


def _edge_crossings(
    view: View, node: np.ndarray, margin: np.ndarray, fine: np.ndarray, s: int, c0: int, r0: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The crossing fractions of the lattice's horizontal edges (node (i, j) to (i, j + 1))
    and vertical edges ((i, j) to (i + 1, j)) beside a fine cell of ``fine`` whose ends
    differ (NaN elsewhere), then the term of ``view_terms`` that is least at each crossing
    (-1 elsewhere). All crossings are found together (one margin evaluation a step)."""
    pad = np.pad(fine, 1)
    beside_h = pad[:-1, 1:-1] | pad[1:, 1:-1]  # (H + 1, W): the cells above and below
    beside_v = pad[1:-1, :-1] | pad[1:-1, 1:]  # (H, W + 1): the cells left and right
    hi_, hj = np.nonzero(beside_h & (node[:, :-1] != node[:, 1:]))
    vi, vj = np.nonzero(beside_v & (node[:-1, :] != node[1:, :]))
    ii, jj = np.concatenate([hi_, vi]), np.concatenate([hj, vj])
    di = np.concatenate([np.zeros(len(hi_), np.intp), np.ones(len(vi), np.intp)])
    dj = 1 - di
    t_h, t_v = np.full(beside_h.shape, np.nan), np.full(beside_v.shape, np.nan)
    a_h = np.full(beside_h.shape, -1, dtype=np.intp)
    a_v = np.full(beside_v.shape, -1, dtype=np.intp)
    if len(ii):
        col, row = jj / s + c0 - 0.5, ii / s + r0 - 0.5
        root = _crossings(view, col, row, dj / s, di / s)
        which = np.argmin(view_terms(view, col + root * dj / s, row + root * di / s), axis=0)
        n = len(hi_)
        t_h[hi_, hj], t_v[vi, vj] = root[:n], root[n:]
        a_h[hi_, hj], a_v[vi, vj] = which[:n], which[n:]
    return t_h, t_v, a_h, a_v


def _corners(
    view: View, p: np.ndarray, q: np.ndarray, ta: np.ndarray, tb: np.ndarray, cell: np.ndarray,
    s: int, c0: int, r0: int,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Where terms ``ta`` and ``tb`` of ``view_terms`` are both 0 (an image corner, or a side
    edge meeting the range) in or beside the fine cells ``cell`` ((N, 2): lattice row, column),
    found by Newton's method from the middle of each segment p -> q (lattice x, y): the
    points (N, 2) and whether each was found there."""
    x = 0.5 * (p + q)
    k = np.arange(len(x))
    step = 1e-3
    for _ in range(_NEWTON_STEPS):
        col, row = x[:, 0] / s + c0 - 0.5, x[:, 1] / s + r0 - 0.5
        f = view_terms(view, np.concatenate([col, col + step / s, col]),
                       np.concatenate([row, row, row + step / s]))  # fmt: skip
        n = len(x)
        fa = f[ta, k], f[ta, k + n], f[ta, k + 2 * n]
        fb = f[tb, k], f[tb, k + n], f[tb, k + 2 * n]
        j11, j12 = (fa[1] - fa[0]) / step, (fa[2] - fa[0]) / step
        j21, j22 = (fb[1] - fb[0]) / step, (fb[2] - fb[0]) / step
        det = j11 * j22 - j12 * j21
        with np.errstate(divide="ignore", invalid="ignore"):
            dx = (j22 * fa[0] - j12 * fb[0]) / det
            dy = (-j21 * fa[0] + j11 * fb[0]) / det
        x = x - np.column_stack([np.nan_to_num(dx), np.nan_to_num(dy)])
        x = np.clip(x, cell[:, ::-1] - 1.0, cell[:, ::-1] + 2.0)
    col, row = x[:, 0] / s + c0 - 0.5, x[:, 1] / s + r0 - 0.5
    f = view_terms(view, col, row)
    small = (np.abs(f[ta, k]) < 1e-4) & (np.abs(f[tb, k]) < 1e-4)
    # in the fine cell or a neighbour (a corner's tip may reach past the lattice's nodes)
    inside = np.all((x > cell[:, ::-1] - 1.0) & (x < cell[:, ::-1] + 2.0), axis=1)
    return x, small & inside


def _outline_segments(
    view: View, node: np.ndarray, margin: np.ndarray, fine: np.ndarray, s: int, c0: int, r0: int
) -> list[np.ndarray]:
    """The footprint's edges on the lattice (x = node column, y = node row), as (N, 2, 2)
    segment arrays: the contour of the view test through the fine cells of ``fine``
    (marching squares), and the parts in view of the lattice edges on ``fine``'s rim."""
    t_h, t_v, a_h, a_v = _edge_crossings(view, node, margin, fine, s, c0, r0)
    segments: list[np.ndarray] = []
    turns: list[tuple[np.ndarray, ...]] = []
    code = (node[:-1, :-1] * 1 + node[:-1, 1:] * 2 + node[1:, 1:] * 4 + node[1:, :-1] * 8).astype(
        np.intp
    )
    code[~fine] = 0
    all_i, all_j = np.nonzero((code > 0) & (code < 15))
    all_code = code[all_i, all_j]
    for case, pairs in _CASES.items():
        pick = all_code == case
        if not pick.any():
            continue
        ii, jj = all_i[pick], all_j[pick]
        fi, fj = ii.astype(np.float64), jj.astype(np.float64)
        side = (
            np.column_stack([fj + t_h[ii, jj], fi]),  # top
            np.column_stack([fj + 1.0, fi + t_v[ii, jj + 1]]),  # right
            np.column_stack([fj + t_h[ii + 1, jj], fi + 1.0]),  # bottom
            np.column_stack([fj, fi + t_v[ii, jj]]),  # left
        )
        term = (a_h[ii, jj], a_v[ii, jj + 1], a_h[ii + 1, jj], a_v[ii, jj])
        for p, q in pairs:
            turn = (term[p] != term[q]) & (term[p] >= 0) & (term[q] >= 0)
            segments.append(np.stack([side[p][~turn], side[q][~turn]], axis=1))
            turns.append((side[p][turn], side[q][turn], term[p][turn], term[q][turn],
                          np.column_stack([ii[turn], jj[turn]])))  # fmt: skip
    if turns:
        # where the edge turns inside a fine cell (two terms meet), it goes through the corner
        a, b, ta, tb, cell = (np.concatenate(parts) for parts in zip(*turns, strict=True))
        c, found = _corners(view, a, b, ta, tb, cell, s, c0, r0)
        segments.append(np.stack([a[~found], b[~found]], axis=1))
        segments.append(np.stack([a[found], c[found]], axis=1))
        segments.append(np.stack([c[found], b[found]], axis=1))
    # the rim: lattice edges with a fine cell of ``fine`` on one side only
    pad = np.pad(fine, 1)
    for rim, a, b, t, (di, dj) in (
        (pad[:-1, 1:-1] != pad[1:, 1:-1], node[:, :-1], node[:, 1:], t_h, (0, 1)),
        (pad[1:-1, :-1] != pad[1:-1, 1:], node[:-1, :], node[1:, :], t_v, (1, 0)),
    ):
        ii, jj = np.nonzero(rim & (a | b))
        if not len(ii):
            continue
        ta = np.where(a[ii, jj], 0.0, t[ii, jj])
        tb = np.where(b[ii, jj], 1.0, t[ii, jj])
        start = np.column_stack([jj + ta * dj, ii + ta * di])
        end = np.column_stack([jj + tb * dj, ii + tb * di])
        segments.append(np.stack([start, end], axis=1))
    return segments
