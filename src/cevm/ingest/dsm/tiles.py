"""Which tile holds a point: tiles grouped by CRS (:class:`CrsTileGroup`: a regular grid of
tiles, or buckets), and the :class:`TileIndex` over them."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from cevm.ingest.dsm.headers import TileHeader, _transformer
from cevm.ingest.dsm.projection import TOLERANCE_PX, to_crs


def _unique_inverse(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(keys, return_inverse=True)``, cheap for spatially coherent keys:
    only the keys at the starts of runs of equal keys are sorted."""
    n = keys.size
    starts = np.flatnonzero(keys[1:] != keys[:-1]) + 1
    if starts.size == 0:
        return keys[:1], np.zeros(n, dtype=np.intp)
    starts = np.concatenate(([0], starts))
    if starts.size <= 64:  # a few runs: sorting in Python costs less than np.unique's setup
        run_keys = keys[starts].tolist()
        uniq_list = sorted(set(run_keys))
        index = {k: i for i, k in enumerate(uniq_list)}
        uniq = np.array(uniq_list, dtype=keys.dtype)
        inv = np.array([index[k] for k in run_keys], dtype=np.intp)
    else:
        uniq, inv = np.unique(keys[starts], return_inverse=True)
    return uniq, np.repeat(inv, np.diff(np.append(starts, n)))


class CrsTileGroup:
    """Tiles sharing a CRS, with a bucket index to find the tile containing a point."""

    def __init__(self, crs_key: str, tile_ids: list[int], tiles: list[TileHeader]):
        self.crs_key = crs_key
        self.tile_ids = np.asarray(tile_ids, dtype=np.int64)
        b = np.array([tiles[i].bounds for i in tile_ids], dtype=np.float64).reshape(-1, 4)
        self.xmin, self.ymin, self.xmax, self.ymax = b.T
        self.bbox = (b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max())
        # Bucket grid: cells of the median tile size; each cell lists the tiles
        # overlapping it, in index order (the first tile containing a point wins).
        size = float(np.median(np.maximum(b[:, 2] - b[:, 0], b[:, 3] - b[:, 1])))
        self.cell = size if size > 0 else 1.0
        # As sorted bucket keys with CSR lists of candidates (ascending tile index).
        self._bkeys: np.ndarray | None = None
        if len(tile_ids) > 8:
            keys: list[int] = []
            cands: list[int] = []
            for k in range(len(tile_ids)):
                cx0, cy0 = self._cell(b[k, 0], b[k, 1])
                cx1, cy1 = self._cell(b[k, 2], b[k, 3])
                for cx in range(int(cx0), int(cx1) + 1):
                    for cy in range(int(cy0), int(cy1) + 1):
                        keys.append(int(self._key(cx, cy)))
                        cands.append(k)
            ka, ca = np.array(keys, dtype=np.int64), np.array(cands, dtype=np.int64)
            order = np.lexsort((ca, ka))
            ka, ca = ka[order], ca[order]
            first = np.concatenate(([True], ka[1:] != ka[:-1]))
            self._bkeys = ka[first]
            self._bptr = np.append(np.flatnonzero(first), ka.size).astype(np.int64)
            self._bcand = ca
        self.lonlat_bbox: dict[str, tuple[float, float, float, float] | None] = {}
        #: agreement asked of a fitted transform into this CRS (:mod:`.projection`)
        self.tolerance = TOLERANCE_PX * float(min(min(abs(tiles[i].a), abs(tiles[i].e)) for i in tile_ids))
        self._grid = self._regular_grid(b) if len(tile_ids) > 8 else None

    #: Largest table of a regular tile grid [cells] (4 bytes each).
    MAX_GRID_CELLS = 4_000_000

    def _regular_grid(self, b: np.ndarray) -> np.ndarray | None:
        """The tiles as a table (row from the top, column from the left) of tile
        indices, -1 for no tile, when they form a regular grid: one size, edges on
        multiples of it from the bounding box's corner, no two in one cell (the usual
        national DSM, e.g. 1 km tiles on the grid's kilometres). None otherwise."""
        w, h = b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]
        tw, th = float(w[0]), float(h[0])
        if not (tw > 0 and th > 0) or np.abs(w - tw).max() > 1e-9 * tw or np.abs(h - th).max() > 1e-9 * th:
            return None
        fc = (b[:, 0] - self.bbox[0]) / tw
        fr = (self.bbox[3] - b[:, 3]) / th
        col, row = np.rint(fc), np.rint(fr)
        if np.abs(fc - col).max() > 1e-6 or np.abs(fr - row).max() > 1e-6:
            return None
        nx, ny = int(col.max()) + 1, int(row.max()) + 1
        if nx * ny > self.MAX_GRID_CELLS:
            return None
        grid = np.full((ny, nx), -1, dtype=np.int32)
        flat = row.astype(np.int64) * nx + col.astype(np.int64)
        if np.unique(flat).size != flat.size:
            return None  # overlapping tiles: the bucket index keeps "first wins"
        grid.reshape(-1)[flat] = np.arange(flat.size, dtype=np.int32)
        self._tw, self._th = tw, th
        return grid

    def _locate_regular(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(tile, undecided): each point's tile on the regular grid, checked against the
        tile's exact bounds; ``undecided`` marks points within rounding of a cell edge
        (or failing the check), which the general index decides."""
        grid = self._grid
        assert grid is not None  # built for a regular layout
        ny, nx = grid.shape
        fc = (x - self.bbox[0]) / self._tw
        fr = (self.bbox[3] - y) / self._th
        with np.errstate(invalid="ignore"):
            inside = (fc >= 0) & (fc < nx) & (fr >= 0) & (fr < ny)
        ci = np.where(inside, fc, 0).astype(np.int64)
        ri = np.where(inside, fr, 0).astype(np.int64)
        k = np.where(inside, grid[ri, ci], -1).astype(np.int64)
        kk = np.maximum(k, 0)
        ok = (k >= 0) & (x >= self.xmin[kk]) & (x < self.xmax[kk]) & (y > self.ymin[kk]) & (y <= self.ymax[kk])
        eps = 1e-7
        near = (np.abs(fc - np.rint(fc)) < eps) | (np.abs(fr - np.rint(fr)) < eps)
        undecided = (k >= 0) & ~ok | (near & np.isfinite(fc) & np.isfinite(fr))
        return np.where(ok, self.tile_ids[kk], -1), undecided

    def _cell(self, x, y):
        return np.floor((x - self.bbox[0]) / self.cell), np.floor((y - self.bbox[1]) / self.cell)

    @staticmethod
    def _key(cx, cy):
        return (np.asarray(cx, dtype=np.int64) + (1 << 30)) * (1 << 31) + (np.asarray(cy, dtype=np.int64) + (1 << 30))

    def locate(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Index (into the sampler's tiles) of the first tile whose footprint holds each
        point (x in [xmin, xmax), y in (ymin, ymax]), -1 for none."""
        out = np.full(x.shape, -1, dtype=np.int64)
        if x.size == 0:
            return out
        if self._bkeys is None:  # few tiles: test each
            for k in range(self.tile_ids.size):
                m = (out < 0) & (x >= self.xmin[k]) & (x < self.xmax[k]) & (y > self.ymin[k]) & (y <= self.ymax[k])
                out[m] = self.tile_ids[k]
            return out
        if self._grid is not None:
            out, undecided = self._locate_regular(x, y)
            if undecided.any():
                u = np.flatnonzero(undecided)
                out[u] = self._locate_buckets(x[u], y[u])
            return out
        return self._locate_buckets(x, y)

    def _locate_buckets(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """:meth:`locate` through the bucket index (any layout of tiles)."""
        out = np.full(x.shape, -1, dtype=np.int64)
        cx, cy = self._cell(x, y)
        ok = np.isfinite(cx) & np.isfinite(cy)
        keys = np.where(ok, self._key(np.where(ok, cx, 0), np.where(ok, cy, 0)), -1)
        bkeys = self._bkeys
        assert bkeys is not None  # built with the bucket index
        pos = np.minimum(np.searchsorted(bkeys, keys), bkeys.size - 1)
        idx = np.flatnonzero(ok & (bkeys[pos] == keys))
        if idx.size == 0:
            return out
        b = pos[idx]
        first, count = self._bptr[b], self._bptr[b + 1] - self._bptr[b]
        xs, ys = x[idx], y[idx]
        got = np.full(idx.size, -1, dtype=np.int64)
        for r in range(int(count.max())):  # candidates of a bucket in order: the first hit wins
            live = (got < 0) & (count > r)
            k = self._bcand[np.where(live, first + r, 0)]
            m = live & (xs >= self.xmin[k]) & (xs < self.xmax[k]) & (ys > self.ymin[k]) & (ys <= self.ymax[k])
            got[m] = self.tile_ids[k[m]]
        out[idx] = got
        return out


class TileIndex:
    """Where the DSM's rasters are: their headers grouped by CRS, each group with a
    bucket index that finds the tile holding a point (the first, in sorted path order,
    where tiles overlap), and per-tile arrays for vectorised pixel arithmetic. Built
    from the headers alone; reads nothing."""

    def __init__(self, tiles: Sequence[TileHeader]):
        self.tiles: list[TileHeader] = list(tiles)
        by_crs: dict[str, list[int]] = {}
        for i, t in enumerate(self.tiles):
            by_crs.setdefault(t.crs_key, []).append(i)
        self.groups = [CrsTileGroup(k, ids, self.tiles) for k, ids in by_crs.items()]
        self.group_of_tile = np.empty(len(self.tiles), dtype=np.int64)
        for gi, grp in enumerate(self.groups):
            self.group_of_tile[grp.tile_ids] = gi
        f = lambda attr: np.array([getattr(t, attr) for t in self.tiles], dtype=np.float64)  # noqa: E731
        self.x0, self.y0, self.a, self.e = f("x0"), f("y0"), f("a"), f("e")
        self.w = np.array([t.width for t in self.tiles], dtype=np.int64)
        self.h = np.array([t.height for t in self.tiles], dtype=np.int64)

    def locate(self, x: np.ndarray, y: np.ndarray, crs: str):
        """The tile holding each point (``x``, ``y`` in ``crs``) and the point in that
        tile's CRS: ``(tile, px, py, pts)``, for the points ``pts`` inside a tile
        (``pts`` None: every point, in order). Non-finite points are in no tile."""
        finite = np.isfinite(x) & np.isfinite(y)
        if len(self.groups) == 1 and bool(finite.all()):
            # Common case, no index arrays: one CRS, every fix finite.
            grp = self.groups[0]
            px, py = to_crs(x, y, crs, grp.crs_key, grp.tolerance)
            t = grp.locate(px, py)
            pts = None
            if not (t >= 0).all():
                pts = np.flatnonzero(t >= 0)
                t, px, py = t[pts], px[pts], py[pts]
            return t, px, py, pts
        live = np.flatnonzero(finite)
        tile = np.full(x.size, -1, dtype=np.int64)
        tx = np.full(x.size, np.nan)
        ty = np.full(x.size, np.nan)
        for grp in self.groups:
            todo = live[tile[live] < 0]
            if todo.size == 0:
                break
            if len(self.groups) > 1:
                todo = todo[self._in_group_bbox(grp, x[todo], y[todo], crs)]
            gx, gy = to_crs(x[todo], y[todo], crs, grp.crs_key, grp.tolerance)
            found = grp.locate(gx, gy)
            hit = found >= 0
            sel = todo[hit]
            tile[sel], tx[sel], ty[sel] = found[hit], gx[hit], gy[hit]
        pts = np.flatnonzero(tile >= 0)
        return tile[pts], tx[pts], ty[pts], pts

    def pixels_holding(self, tile: np.ndarray, cx: np.ndarray, cy: np.ndarray):
        """For points (``cx``, ``cy``) in the CRS of ``tile`` (one per point): the tile
        of that CRS whose pixel area holds each, and the pixel's row and column
        (``(sel, tile, row, col)`` for the points ``sel`` that some tile holds)."""
        sels, tiles, rows, cols = [], [], [], []
        grp = self.group_of_tile[tile]
        for gi in np.unique(grp).tolist():
            sel = np.flatnonzero(grp == gi)
            nt = self.groups[gi].locate(cx[sel], cy[sel])
            ok = nt >= 0
            sel, nt = sel[ok], nt[ok]
            col = np.floor((cx[sel] - self.x0[nt]) / self.a[nt]).astype(np.int64)
            row = np.floor((cy[sel] - self.y0[nt]) / self.e[nt]).astype(np.int64)
            sels.append(sel)
            tiles.append(nt)
            rows.append(np.clip(row, 0, self.h[nt] - 1))
            cols.append(np.clip(col, 0, self.w[nt] - 1))
        if len(sels) == 1:
            return sels[0], tiles[0], rows[0], cols[0]
        return tuple(np.concatenate(a) if a else np.empty(0, dtype=np.int64) for a in (sels, tiles, rows, cols))

    @staticmethod
    def _in_group_bbox(grp: CrsTileGroup, x: np.ndarray, y: np.ndarray, crs: str) -> np.ndarray:
        """Cheap pre-filter: points inside the group's bounding box seen in ``crs``
        (with a 1 % margin). Everything passes if the box cannot be computed."""
        if crs not in grp.lonlat_bbox:
            try:
                tr = _transformer(grp.crs_key, crs)
                xmin, ymin, xmax, ymax = tr.transform_bounds(*grp.bbox, densify_pts=21)
                mx, my = 0.01 * (xmax - xmin), 0.01 * (ymax - ymin)
                padded = (xmin - mx, ymin - my, xmax + mx, ymax + my)
                grp.lonlat_bbox[crs] = padded if all(map(math.isfinite, padded)) and xmin <= xmax else None
            except Exception:
                grp.lonlat_bbox[crs] = None
        box = grp.lonlat_bbox[crs]
        if box is None:
            return np.ones(x.size, dtype=bool)
        return (x >= box[0]) & (x <= box[2]) & (y >= box[1]) & (y <= box[3])
