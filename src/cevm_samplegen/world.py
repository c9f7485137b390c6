"""The world of the sample logs: terrain, roads, surface objects and the DSM tiles."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cevm_samplegen.common import BNG, DEFAULT_SEED, WORLD_ORIGIN_EN, seeded_rng


@dataclass(frozen=True, eq=False)
class Terrain:
    """Smooth hills: ``base_m + sum_i amp_i cos(kx_i (x - x0) + ky_i (y - y0) + phase_i)``
    in BNG metres. Each wave's maximum grade is 0.4-1.2 %; roads follow it (the road
    surface IS the terrain)."""

    base_m: float
    kx: np.ndarray
    ky: np.ndarray
    amp_m: np.ndarray
    phase: np.ndarray

    def elevation_m(self, x, y) -> np.ndarray:
        """Terrain height [m above mean sea level] at BNG easting ``x``, northing ``y`` [m]."""
        x = np.asarray(x, dtype=float) - WORLD_ORIGIN_EN[0]
        y = np.asarray(y, dtype=float) - WORLD_ORIGIN_EN[1]
        out = np.full(np.broadcast(x, y).shape, self.base_m)
        for kx, ky, a, ph in zip(self.kx, self.ky, self.amp_m, self.phase, strict=True):
            out += a * np.cos(kx * x + ky * y + ph)
        return out


def make_terrain(seed: int) -> Terrain:
    """Eight waves, wavelengths log-uniform in 0.7-16 km, random directions, amplitude =
    grade x wavelength / 2 pi with grade uniform in 0.4-1.2 %; base 95 m (Milton Keynes
    lies at 60-150 m)."""
    rng = seeded_rng(seed, "terrain")
    n = 8
    lam = np.exp(rng.uniform(np.log(700.0), np.log(16000.0), n))
    theta = rng.uniform(0.0, np.pi, n)
    grade = rng.uniform(0.004, 0.012, n)
    k = 2 * np.pi / lam
    return Terrain(
        base_m=95.0, kx=k * np.cos(theta), ky=k * np.sin(theta), amp_m=grade * lam / (2 * np.pi),
        phase=rng.uniform(0, 2 * np.pi, n),
    )


@dataclass(frozen=True, eq=False)
class Route:
    """A road polyline in BNG, resampled every metre along its length.

    ``closed`` routes are loops (distance wraps modulo the length); open routes are
    driven out and back (distance reflects at each end: a U-turn at a junction).
    """

    name: str
    closed: bool
    s_m: np.ndarray  # along-route position of the points [m], 0 .. length
    x_m: np.ndarray
    y_m: np.ndarray

    @property
    def length_m(self) -> float:
        return float(self.s_m[-1])

    def along_m(self, distance_m) -> np.ndarray:
        """Position along the centreline [m] after driving ``distance_m`` from s = 0."""
        d = np.asarray(distance_m, dtype=float)
        L = self.length_m
        if self.closed:
            return np.mod(d, L)
        s = np.mod(d, 2 * L)
        return np.where(s > L, 2 * L - s, s)

    def xy(self, distance_m) -> tuple[np.ndarray, np.ndarray]:
        """BNG easting, northing [m] after driving ``distance_m`` from s = 0."""
        s = self.along_m(distance_m)
        return np.interp(s, self.s_m, self.x_m), np.interp(s, self.s_m, self.y_m)


#: Road control points in BNG metres around Milton Keynes: (closed, points). Smoothed by
#: a cubic spline through the points (periodic for loops).
ROUTE_POINTS: dict[str, tuple[bool, tuple[tuple[float, float], ...]]] = {
    # Urban bus loops (about 9 km and 8 km), through central Milton Keynes.
    "bus-1": (True, ((484200, 237400), (485300, 237050), (486400, 237500), (486950, 238550),
                     (486300, 239700), (485100, 240150), (484000, 239650), (483550, 238500))),
    "bus-2": (True, ((485600, 236200), (486500, 235750), (487300, 236000), (488300, 236900),
                     (488150, 238250), (487050, 238950), (486050, 238450), (485350, 237350))),
    # Regional delivery loop (about 27 km) through the surrounding villages.
    "regional": (True, ((487500, 235100), (490000, 236000), (490900, 238500), (489800, 241500),
                        (487000, 242700), (484000, 242300), (481900, 240600), (481500, 237600),
                        (483200, 235200), (485500, 234500))),
    # Trunk road north-west towards the East Midlands (about 110 km), driven out and back.
    "trunk": (False, ((488900, 240800), (489600, 243000), (487600, 246000), (484000, 250500),
                      (479000, 257000), (474000, 265000), (470000, 273000), (466500, 281000),
                      (462000, 289000), (458500, 297000), (452000, 312000), (446000, 323000),
                      (440000, 333000))),
}


def make_route(name: str, step_m: float = 1.0) -> Route:
    """Smooth :data:`ROUTE_POINTS` ``name`` with a cubic spline through the points
    (parameterised by chord length) and resample it every ``step_m`` metres of arc."""
    from scipy.interpolate import CubicSpline

    closed, pts = ROUTE_POINTS[name]
    p = np.asarray(pts, dtype=float)
    if closed:
        p = np.vstack([p, p[:1]])
    chord = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))))
    cs = CubicSpline(chord, p, bc_type="periodic" if closed else "natural")
    u = np.linspace(0.0, chord[-1], int(chord[-1] / (step_m / 4.0)) + 2)
    xy = cs(u)
    s = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))))
    s_new = np.concatenate((np.arange(0.0, s[-1], step_m), [s[-1]]))
    return Route(name, closed, s_new, np.interp(s_new, s, xy[:, 0]), np.interp(s_new, s, xy[:, 1]))


@dataclass(frozen=True)
class DsmSpec:
    """Where and how the DSM tiles are made.

    ``tile_m = 1000``: 1 km tiles, the Ordnance Survey grid the UK's LIDAR products use.
    ``resolution_m = 2.0``: the Environment Agency's 2 m composite DSM. ``quantum_m =
    1/128``: rounding step of the stored heights, exact in binary floating point (half
    the compressed size of 0.01 m). ``survey_box`` (E0, N0, E1, N1): tiles exist only
    inside it. ``omitted_cells``: SW corners of 1 km cells left out on purpose.
    """

    tile_m: float = 1000.0
    resolution_m: float = 2.0
    quantum_m: float = 1.0 / 128.0
    survey_box: tuple[float, float, float, float] = (480000.0, 233000.0, 492000.0, 245000.0)
    omitted_cells: tuple[tuple[float, float], ...] = ((481000.0, 239000.0),)
    nodata: float = -9999.0


@dataclass(frozen=True, eq=False)
class SurfaceObjects:
    """Objects standing on the terrain (or holes in the survey), as flat arrays.

    Rectangles (buildings, bridge decks): centre, unit vector (ux, uy) of the half-length
    axis, half-length, half-width, absolute top height [m]. Discs (tree canopies):
    centre, radius, ground height, canopy height above ground. Holes: centre, radius.
    """

    rect_kind: np.ndarray  # "building" | "bridge"
    rect_cx: np.ndarray
    rect_cy: np.ndarray
    rect_ux: np.ndarray
    rect_uy: np.ndarray
    rect_hl: np.ndarray
    rect_hw: np.ndarray
    rect_top: np.ndarray
    tree_cx: np.ndarray
    tree_cy: np.ndarray
    tree_r: np.ndarray
    tree_ground: np.ndarray
    tree_h: np.ndarray
    hole_cx: np.ndarray
    hole_cy: np.ndarray
    hole_r: np.ndarray


@dataclass(frozen=True, eq=False)
class World:
    """Terrain, routes, surface objects and the DSM tile set of one seed."""

    seed: int
    terrain: Terrain
    routes: dict[str, Route]
    objects: SurfaceObjects
    dsm: DsmSpec
    tiles: tuple[tuple[float, float], ...]  # SW corners of the tiles, sorted

    def in_tiles(self, x, y) -> np.ndarray:
        """True where BNG points (x, y) lie inside a DSM tile."""
        t = self.dsm.tile_m
        cells = {(float(a), float(b)) for a, b in self.tiles}
        cx, cy = _cell_of(x, y, t)
        keys = np.round(cx).astype(np.int64) * 10_000_000 + np.round(cy).astype(np.int64)
        have = np.array([int(a) * 10_000_000 + int(b) for a, b in cells], dtype=np.int64)
        return np.isin(keys, have)


def _cell_of(x, y, tile_m: float) -> tuple[np.ndarray, np.ndarray]:
    """SW corner of the tile cell holding each point, with the raster convention of
    :class:`cevm.ingest.dsm.DsmSampler`: x in [x0, x0 + t), y in (y0, y0 + t]."""
    cx = np.floor(np.asarray(x, dtype=float) / tile_m) * tile_m
    cy = (np.ceil(np.asarray(y, dtype=float) / tile_m) - 1.0) * tile_m
    return cx, cy


def _in_box(x, y, box, margin=0.0):
    return (x >= box[0] - margin) & (x <= box[2] + margin) & (y >= box[1] - margin) & (y <= box[3] + margin)


#: Object densities per route: (building spacing range [m] per side, off-road tree
#: spacing range [m] per side, trees over the road per km, bridges on the route).
_DENSITY = {
    "bus-1": ((12.0, 30.0), (30.0, 80.0), 0.6, 1),
    "bus-2": ((12.0, 30.0), (30.0, 80.0), 0.6, 1),
    "regional": ((40.0, 160.0), (20.0, 60.0), 0.5, 2),
    "trunk": ((150.0, 400.0), (40.0, 120.0), 0.4, 1),
}


def _route_frame(route: Route, s):
    """Position (x, y) and unit direction (ux, uy) of ``route`` at distances ``s`` [m]."""
    x = np.interp(s, route.s_m, route.x_m)
    y = np.interp(s, route.s_m, route.y_m)
    ds = 1.0
    dx = np.interp(s + ds, route.s_m, route.x_m) - np.interp(s - ds, route.s_m, route.x_m)
    dy = np.interp(s + ds, route.s_m, route.y_m) - np.interp(s - ds, route.s_m, route.y_m)
    n = np.hypot(dx, dy)
    return x, y, dx / n, dy / n


def _clear_of_roads(tree, cx, cy, extent, clearance):
    """Whether objects at (cx, cy) of ``extent`` keep ``clearance`` [m] from every road
    centreline (``tree``: a KD-tree of the routes' points)."""
    d, _ = tree.query(np.column_stack([cx, cy]))
    return d > extent + clearance


def _beside_road(route: Route, side: float, s_lo: float, s_hi: float, bsp: tuple[float, float],
                 tsp: tuple[float, float], tree, terrain: Terrain, box,
                 rng: np.random.Generator, R: dict[str, list[np.ndarray]], T: dict[str, list[np.ndarray]]) -> None:
    """Buildings (into ``R``) and off-road trees (into ``T``) on one ``side`` of a route's
    stretch ``s_lo``..``s_hi``, spaced by ``bsp`` and ``tsp`` [m], clear of every road."""
    span = s_hi - s_lo
    n = int(span / bsp[0]) + 2
    s = s_lo + np.cumsum(rng.uniform(*bsp, n))
    s = s[s < s_hi]
    m = s.size
    x, y, ux, uy = _route_frame(route, s)
    hl, hw = rng.uniform(4.0, 12.0, m), rng.uniform(3.0, 7.0, m)
    off = rng.uniform(12.0, 35.0, m)
    cx, cy = x - side * uy * off, y + side * ux * off
    height = rng.uniform(4.0, 14.0, m)
    ok = _clear_of_roads(tree, cx, cy, np.hypot(hl, hw), 8.0) & _in_box(cx, cy, box, 50.0)
    R["kind"].append(np.full(int(ok.sum()), "building"))
    for k, v in (("cx", cx), ("cy", cy), ("ux", ux), ("uy", uy), ("hl", hl), ("hw", hw)):
        R[k].append(v[ok])
    R["top"].append(terrain.elevation_m(cx[ok], cy[ok]) + height[ok])
    # Off-road trees.
    n = int(span / tsp[0]) + 2
    s = s_lo + np.cumsum(rng.uniform(*tsp, n))
    s = s[s < s_hi]
    m = s.size
    x, y, ux, uy = _route_frame(route, s)
    r = rng.uniform(2.0, 5.0, m)
    off = rng.uniform(7.0, 30.0, m)
    cx, cy = x - side * uy * off, y + side * ux * off
    ok = _clear_of_roads(tree, cx, cy, r, 6.0) & _in_box(cx, cy, box, 50.0)
    T["cx"].append(cx[ok])
    T["cy"].append(cy[ok])
    T["r"].append(r[ok])
    T["ground"].append(terrain.elevation_m(cx[ok], cy[ok]))
    T["h"].append(rng.uniform(5.0, 14.0, m)[ok])


def _place_objects(seed: int, terrain: Terrain, routes: dict[str, Route], dsm: DsmSpec) -> SurfaceObjects:
    """Draw buildings, trees, bridges and holes beside and over the routes, inside the
    survey box. Buildings and off-road trees keep clear of every road centreline (8 m and
    6 m plus their own extent); trees over the road, bridges and some holes sit on it."""
    from scipy.spatial import cKDTree

    pts = np.concatenate([np.column_stack([r.x_m[::2], r.y_m[::2]]) for r in routes.values()])
    tree = cKDTree(pts)
    box = dsm.survey_box
    R: dict[str, list[np.ndarray]] = {k: [] for k in ("kind", "cx", "cy", "ux", "uy", "hl", "hw", "top")}
    T: dict[str, list[np.ndarray]] = {k: [] for k in ("cx", "cy", "r", "ground", "h")}
    H: dict[str, list[np.ndarray]] = {k: [] for k in ("cx", "cy", "r")}

    for name in sorted(routes):
        route = routes[name]
        rng = seeded_rng(seed, "objects", name)
        bsp, tsp, trees_per_km, n_bridges = _DENSITY.get(name, _DENSITY["regional"])
        inside = _in_box(route.x_m, route.y_m, box, 200.0)
        if not inside.any():
            continue
        s_lo, s_hi = float(route.s_m[inside].min()), float(route.s_m[inside].max())
        span = s_hi - s_lo
        for side in (-1.0, 1.0):  # buildings and off-road trees, both sides
            _beside_road(route, side, s_lo, s_hi, bsp, tsp, tree, terrain, box, rng, R, T)
        # Trees over the road.
        m = max(1, int(round(span / 1000.0 * trees_per_km)))
        s = rng.uniform(s_lo, s_hi, m)
        x, y, ux, uy = _route_frame(route, s)
        lat = rng.uniform(-2.0, 2.0, m)
        cx, cy = x - uy * lat, y + ux * lat
        T["cx"].append(cx)
        T["cy"].append(cy)
        T["r"].append(rng.uniform(3.0, 5.0, m))
        T["ground"].append(terrain.elevation_m(cx, cy))
        T["h"].append(rng.uniform(7.0, 12.0, m))
        # Bridges: a deck across the road, 6.5-7.5 m above it.
        s = rng.uniform(s_lo + 0.1 * span, s_hi - 0.1 * span, n_bridges)
        x, y, ux, uy = _route_frame(route, s)
        R["kind"].append(np.full(n_bridges, "bridge"))
        R["cx"].append(x)
        R["cy"].append(y)
        R["ux"].append(-uy)
        R["uy"].append(ux)
        R["hl"].append(np.full(n_bridges, 25.0))
        R["hw"].append(rng.uniform(5.0, 7.5, n_bridges))
        R["top"].append(terrain.elevation_m(x, y) + rng.uniform(6.5, 7.5, n_bridges))
        # Holes on the road (a LIDAR void over wet tarmac, say).
        m = 2
        s = rng.uniform(s_lo, s_hi, m)
        x, y, _, _ = _route_frame(route, s)
        H["cx"].append(x)
        H["cy"].append(y)
        H["r"].append(rng.uniform(3.0, 8.0, m))
    # Off-road holes (water, voids): about one per km^2 of the survey box.
    rng = seeded_rng(seed, "holes")
    area_km2 = (box[2] - box[0]) * (box[3] - box[1]) / 1e6
    m = max(1, int(round(area_km2)))
    H["cx"].append(rng.uniform(box[0], box[2], m))
    H["cy"].append(rng.uniform(box[1], box[3], m))
    H["r"].append(rng.uniform(5.0, 25.0, m))

    def cat(d, k, dtype=float):
        return np.concatenate(d[k]).astype(dtype) if d[k] else np.zeros(0, dtype=dtype)

    return SurfaceObjects(
        rect_kind=cat(R, "kind", object), rect_cx=cat(R, "cx"), rect_cy=cat(R, "cy"),
        rect_ux=cat(R, "ux"), rect_uy=cat(R, "uy"), rect_hl=cat(R, "hl"), rect_hw=cat(R, "hw"),
        rect_top=cat(R, "top"), tree_cx=cat(T, "cx"), tree_cy=cat(T, "cy"), tree_r=cat(T, "r"),
        tree_ground=cat(T, "ground"), tree_h=cat(T, "h"), hole_cx=cat(H, "cx"), hole_cy=cat(H, "cy"),
        hole_r=cat(H, "r"),
    )


def _tile_set(routes: dict[str, Route], dsm: DsmSpec) -> tuple[tuple[float, float], ...]:
    """SW corners of the tiles: cells any route touches, inside the survey box, minus the
    omitted cells; sorted."""
    t = dsm.tile_m
    box = dsm.survey_box
    cells: set[tuple[float, float]] = set()
    for r in routes.values():
        cx, cy = _cell_of(r.x_m, r.y_m, t)
        ok = (cx >= box[0]) & (cx + t <= box[2]) & (cy >= box[1]) & (cy + t <= box[3])
        cells.update(zip(cx[ok].tolist(), cy[ok].tolist(), strict=True))
    cells -= {(float(a), float(b)) for a, b in dsm.omitted_cells}
    return tuple(sorted(cells))


def build_world(seed: int = DEFAULT_SEED, dsm: DsmSpec = DsmSpec(), route_names: Sequence[str] | None = None) -> World:
    """Terrain, routes (all of :data:`ROUTE_POINTS` unless ``route_names``), surface
    objects and DSM tile set for ``seed``. Pure and deterministic."""
    names = sorted(route_names) if route_names is not None else sorted(ROUTE_POINTS)
    terrain = make_terrain(seed)
    routes = {n: make_route(n) for n in names}
    objects = _place_objects(seed, terrain, routes, dsm)
    return World(seed, terrain, routes, objects, dsm, _tile_set(routes, dsm))


def dsm_tile(world: World, e0: float, n0: float) -> np.ndarray:
    """The DSM of the tile with SW corner (e0, n0) [m]: float32 rows north to south,
    pixel centres at e0 + (col + 0.5) r, n0 + tile - (row + 0.5) r; heights rounded to
    ``quantum_m``; ``nodata`` in holes."""
    spec = world.dsm
    res = spec.resolution_m
    n = int(round(spec.tile_m / res))
    xs = e0 + (np.arange(n) + 0.5) * res
    ys = n0 + spec.tile_m - (np.arange(n) + 0.5) * res
    z = world.terrain.elevation_m(xs[None, :], ys[:, None])
    o = world.objects

    def window(cx, cy, rad):
        c0 = max(0, int(np.floor((cx - rad - e0) / res)))
        c1 = min(n, int(np.ceil((cx + rad - e0) / res)) + 1)
        r0 = max(0, int(np.floor((n0 + spec.tile_m - (cy + rad)) / res)))
        r1 = min(n, int(np.ceil((n0 + spec.tile_m - (cy - rad)) / res)) + 1)
        return r0, r1, c0, c1

    def near(cx, cy, rad):
        return np.flatnonzero((cx + rad >= e0) & (cx - rad <= e0 + spec.tile_m)
                              & (cy + rad >= n0) & (cy - rad <= n0 + spec.tile_m))

    rad = np.hypot(o.rect_hl, o.rect_hw)
    for i in near(o.rect_cx, o.rect_cy, rad):
        r0, r1, c0, c1 = window(o.rect_cx[i], o.rect_cy[i], rad[i])
        if r0 >= r1 or c0 >= c1:
            continue
        dx = xs[None, c0:c1] - o.rect_cx[i]
        dy = ys[r0:r1, None] - o.rect_cy[i]
        du = dx * o.rect_ux[i] + dy * o.rect_uy[i]
        dv = -dx * o.rect_uy[i] + dy * o.rect_ux[i]
        inside = (np.abs(du) <= o.rect_hl[i]) & (np.abs(dv) <= o.rect_hw[i])
        sub = z[r0:r1, c0:c1]
        sub[inside] = np.maximum(sub[inside], o.rect_top[i])
    for i in near(o.tree_cx, o.tree_cy, o.tree_r):
        r0, r1, c0, c1 = window(o.tree_cx[i], o.tree_cy[i], o.tree_r[i])
        if r0 >= r1 or c0 >= c1:
            continue
        q = ((xs[None, c0:c1] - o.tree_cx[i]) ** 2 + (ys[r0:r1, None] - o.tree_cy[i]) ** 2) / o.tree_r[i] ** 2
        canopy = o.tree_ground[i] + o.tree_h[i] * np.sqrt(np.clip(1.0 - q, 0.0, None))
        sub = z[r0:r1, c0:c1]
        np.maximum(sub, np.where(q < 1.0, canopy, -np.inf), out=sub)
    z = np.round(z / spec.quantum_m) * spec.quantum_m
    for i in near(o.hole_cx, o.hole_cy, o.hole_r):
        r0, r1, c0, c1 = window(o.hole_cx[i], o.hole_cy[i], o.hole_r[i])
        if r0 >= r1 or c0 >= c1:
            continue
        q = (xs[None, c0:c1] - o.hole_cx[i]) ** 2 + (ys[r0:r1, None] - o.hole_cy[i]) ** 2
        z[r0:r1, c0:c1][q <= o.hole_r[i] ** 2] = spec.nodata
    return z.astype(np.float32)


def os_tile_name(e0: float, n0: float) -> str:
    """Ordnance Survey grid reference of the 1 km cell with SW corner (e0, n0), e.g.
    ``SP8538`` for (485000, 238000)."""
    e, n = int(e0), int(n0)
    e100, n100 = e // 100000, n // 100000
    l1 = (19 - n100) - (19 - n100) % 5 + (e100 + 10) // 5
    l2 = (19 - n100) * 5 % 25 + e100 % 5
    letters = "ABCDEFGHJKLMNOPQRSTUVWXYZ"  # no I
    return f"{letters[l1]}{letters[l2]}{(e % 100000) // 1000:02d}{(n % 100000) // 1000:02d}"


def tile_filename(world: World, e0: float, n0: float) -> str:
    r = world.dsm.resolution_m
    rs = f"{r:g}".replace(".", "P")
    return f"{os_tile_name(e0, n0)}_DSM_{rs}M.tif"


def write_dsm_tiles(world: World, outdir: Path) -> list[Path]:
    """Write every tile of ``world`` as a tiled, deflate-compressed (floating-point
    predictor) float32 GeoTIFF in EPSG:27700; returns the paths, sorted."""
    import rasterio
    from affine import Affine

    outdir.mkdir(parents=True, exist_ok=True)
    spec = world.dsm
    n = int(round(spec.tile_m / spec.resolution_m))
    paths = []
    for e0, n0 in world.tiles:
        z = dsm_tile(world, e0, n0)
        path = outdir / tile_filename(world, e0, n0)
        profile = dict(
            driver="GTiff", width=n, height=n, count=1, dtype="float32", crs=BNG,
            transform=Affine(spec.resolution_m, 0.0, e0, 0.0, -spec.resolution_m, n0 + spec.tile_m),
            nodata=spec.nodata, compress="deflate", predictor=3, zlevel=6, tiled=True,
            blockxsize=256, blockysize=256,
        )
        with rasterio.open(path, "w", **profile) as ds:
            ds.write(z, 1)
        paths.append(path)
    return sorted(paths)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges [i0, i1] (inclusive) of the True runs of ``mask``."""
    m = np.concatenate(([False], mask, [False])).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1).tolist(), (np.flatnonzero(d == -1) - 1).tolist(), strict=True))


def route_dsm_summary(world: World, route: Route) -> dict:
    """Intervals of ``route`` [m along it] outside every DSM tile, and intervals where a
    surface object (tree, bridge, building, hole) lies within 1.5 pixels + 0.5 m of the
    centreline (the raw DSM road profile there is spiky or missing)."""
    from scipy.spatial import cKDTree

    s, x, y = route.s_m, route.x_m, route.y_m
    gaps = [[round(float(s[a]), 1), round(float(s[b]), 1)] for a, b in _runs(~world.in_tiles(x, y))]
    o = world.objects
    margin = 1.5 * world.dsm.resolution_m + 0.5
    tree = cKDTree(np.column_stack([x, y]))
    hit: dict[str, np.ndarray] = {k: np.zeros(s.size, bool) for k in ("bridge", "building", "hole", "tree")}
    rad = np.hypot(o.rect_hl, o.rect_hw) + margin
    hits = tree.query_ball_point(np.column_stack([o.rect_cx, o.rect_cy]), rad) if o.rect_cx.size else []
    for i, idx in enumerate(hits):
        if not idx:
            continue
        idx = np.asarray(idx)
        dx, dy = x[idx] - o.rect_cx[i], y[idx] - o.rect_cy[i]
        du = dx * o.rect_ux[i] + dy * o.rect_uy[i]
        dv = -dx * o.rect_uy[i] + dy * o.rect_ux[i]
        hit[o.rect_kind[i]][idx[(np.abs(du) <= o.rect_hl[i] + margin) & (np.abs(dv) <= o.rect_hw[i] + margin)]] = True
    for kind, cx, cy, r in (("tree", o.tree_cx, o.tree_cy, o.tree_r), ("hole", o.hole_cx, o.hole_cy, o.hole_r)):
        if not cx.size:
            continue
        for idx in tree.query_ball_point(np.column_stack([cx, cy]), r + margin):
            if idx:
                hit[kind][np.asarray(idx)] = True
    objects = []
    for kind in sorted(hit):
        for a, b in _runs(hit[kind]):
            objects.append({"kind": kind, "from_m": round(float(s[a]), 1), "to_m": round(float(s[b]), 1)})
    objects.sort(key=lambda d: (d["from_m"], d["kind"]))
    return {"closed": route.closed, "length_m": round(route.length_m, 1), "dsm_gaps_m": gaps,
            "surface_objects": objects}


