"""Static road-scene geometry: carriageways, lanes, markings, shoulders, verges, barriers, poles, signs, trees.

Everything is built as flat-shaded triangle soup in the road world frame (see :mod:`.scenario`).  Ground
layers (z = 0) are kept apart from raised objects because the renderer paints them in order without depth
testing (coplanar layers would z-fight otherwise).  Each vertex carries a material id the shader uses to
pick its procedural texture.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .scenario import RoadSpec

# material ids shared with the shaders in render.py
MAT_PLAIN, MAT_ASPHALT, MAT_GRASS, MAT_PAINT, MAT_METAL, MAT_CONCRETE, MAT_FOLIAGE, MAT_LAMP, MAT_SIGN = range(9)
MAT_BODY, MAT_GLASS, MAT_RUBBER, MAT_HEADLIGHT, MAT_TAILLIGHT, MAT_PLATE, MAT_TRIM = range(10, 17)


@dataclass(frozen=True)
class Curve:
    """A gentle bend of the road: the centre line is y = (x - start)² / (2 radius) beyond ``start``."""

    start: float
    radius: float  # signed: + bends to the left (+y)

    def offset(self, x):
        d = np.maximum(np.asarray(x, float) - self.start, 0.0)
        return d * d / (2 * self.radius)

    def slope(self, x):
        return np.maximum(np.asarray(x, float) - self.start, 0.0) / self.radius

    def bend(self, rows: np.ndarray) -> np.ndarray:
        """Displace vertex rows (x, y, z, ...) sideways with the bend."""
        out = rows.copy()
        out[:, 1] += self.offset(rows[:, 0]).astype(out.dtype)
        return out


def road_curve(road: RoadSpec) -> Curve | None:
    return Curve(road.curve_start, road.curve_radius) if road.curve_radius else None


@dataclass
class MeshBuilder:
    """Accumulates triangles (position, normal, colour, material) as one vertex array.

    With ``seg`` > 0, quads longer than ``seg`` along x are cut into strips so that a road bend can displace
    their vertices."""

    chunks: list[np.ndarray] = field(default_factory=list)
    seg: float = 0.0

    def triangles(self, P: np.ndarray, colour, material: int, normals: np.ndarray | None = None) -> None:
        """P: (T, 3, 3) triangles, counter-clockwise seen from outside."""
        P = np.asarray(P, np.float32).reshape(-1, 3, 3)
        if normals is None:
            n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            normals = np.repeat(n[:, None], 3, axis=1)
        col = np.broadcast_to(np.asarray(colour, np.float32), (P.shape[0], 3, 3))
        mat = np.full((P.shape[0], 3, 1), material, np.float32)
        self.chunks.append(np.concatenate([P, np.asarray(normals, np.float32).reshape(-1, 3, 3), col, mat],
                                          axis=2).reshape(-1, 10))

    def quad(self, a, b, c, d, colour, material: int) -> None:
        """Quad a-b-c-d counter-clockwise seen from outside."""
        a, b, c, d = (np.asarray(v, np.float64) for v in (a, b, c, d))
        span_ab = max(abs(b[0] - a[0]), abs(c[0] - d[0]))
        span_ad = max(abs(d[0] - a[0]), abs(c[0] - b[0]))
        if self.seg > 0 and max(span_ab, span_ad) > self.seg:
            if span_ad > span_ab:  # cut along a->d instead: rotate the corner order
                a, b, c, d = d, a, b, c
            n = int(np.ceil(max(span_ab, span_ad) / self.seg))
            s = np.linspace(0, 1, n + 1)[:, None]
            top, bot = a + (b - a) * s, d + (c - d) * s
            tri = np.concatenate([np.stack([top[:-1], top[1:], bot[1:]], 1), np.stack([top[:-1], bot[1:], bot[:-1]], 1)])
            self.triangles(tri.astype(np.float32), colour, material)
            return
        self.triangles(np.array([[a, b, c], [a, c, d]], np.float32), colour, material)

    def ground_rect(self, x0, x1, y0, y1, colour, material: int, z: float = 0.0) -> None:
        self.quad((x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z), colour, material)

    def ground_rects(self, x0, x1, y0, y1, colour, material: int) -> None:
        """Many short axis-aligned ground rectangles at once (arrays of equal length; not cut for bends)."""
        x0, x1, y0, y1 = (np.asarray(v, np.float32) for v in (x0, x1, y0, y1))
        z = np.zeros_like(x0)
        a, b = np.stack([x0, y0, z], 1), np.stack([x1, y0, z], 1)
        c, d = np.stack([x1, y1, z], 1), np.stack([x0, y1, z], 1)
        tri = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
        self.triangles(tri, colour, material)

    def box(self, centre, size, colour, material: int, yaw: float = 0.0) -> None:
        """Axis-aligned (then yawed) box; centre is the centre of its bottom face."""
        cx, cy, cz = centre
        lx, ly, lz = (s / 2 for s in size)
        corners = np.array([[sx * lx, sy * ly, sz] for sz in (0, 2 * lz) for sy in (-1, 1) for sx in (-1, 1)],
                           np.float32)
        c, s = np.cos(yaw), np.sin(yaw)
        corners[:, :2] = corners[:, :2] @ np.array([[c, s], [-s, c]], np.float32)
        corners += np.array([cx, cy, cz], np.float32)
        # indices: bottom 0..3 (y-,x-),(y-,x+),(y+,x-),(y+,x+); top 4..7
        faces = [(0, 1, 5, 4), (1, 3, 7, 5), (3, 2, 6, 7), (2, 0, 4, 6), (4, 5, 7, 6), (0, 2, 3, 1)]
        for f in faces:
            self.quad(*corners[list(f)], colour, material)

    def prism(self, base, radius_bottom, radius_top, height, colour, material: int, sides: int = 8,
              cap: bool = True) -> None:
        """Vertical n-sided prism / cone frustum standing on ``base``."""
        a = np.linspace(0, 2 * np.pi, sides + 1)
        ring = np.stack([np.cos(a), np.sin(a)], 1)
        b = np.asarray(base, np.float32)
        lo = np.column_stack([b[0] + radius_bottom * ring[:, 0], b[1] + radius_bottom * ring[:, 1],
                              np.full(sides + 1, b[2])])
        hi = np.column_stack([b[0] + radius_top * ring[:, 0], b[1] + radius_top * ring[:, 1],
                              np.full(sides + 1, b[2] + height)])
        tri = []
        for i in range(sides):
            tri += [[lo[i], lo[i + 1], hi[i + 1]], [lo[i], hi[i + 1], hi[i]]]
            if cap and radius_top > 0:
                tri.append([hi[i], hi[i + 1], b + [0, 0, height]])
        self.triangles(np.array(tri, np.float32), colour, material)

    def array(self) -> np.ndarray:
        if not self.chunks:
            return np.zeros((0, 10), np.float32)
        return np.concatenate(self.chunks).astype(np.float32)


@dataclass
class RoadLayout:
    """Lateral positions (world y, metres) of the lanes of each carriageway."""

    road: RoadSpec

    def lane_centre(self, direction: int, lane: int) -> float:
        """Centre of ``lane`` (0 = the outermost, slow lane) of carriageway ``direction``.

        Direction 0 (traffic along +x) keeps to the right side of the road (negative y); direction 1 to the
        left side (positive y).
        """
        r = self.road
        inner = r.median / 2 if r.directions == 2 else -r.carriageway_width / 2
        if r.directions == 1:
            # one-way road: lane 0 is the right-hand lane of the traffic (y = -W/2 side when it drives along +x)
            y = -r.carriageway_width / 2 + (lane + 0.5) * r.lane_width
            return y if direction == 0 else -y
        y = inner + r.carriageway_width - (lane + 0.5) * r.lane_width
        return -y if direction == 0 else y

    def carriageway_edges(self, direction: int) -> tuple[float, float]:
        """(min y, max y) of a carriageway's lanes."""
        r = self.road
        if r.directions == 1:
            return -r.carriageway_width / 2, r.carriageway_width / 2
        a, b = r.median / 2, r.median / 2 + r.carriageway_width
        return (-b, -a) if direction == 0 else (a, b)

    @property
    def half_width(self) -> float:
        """Half the width of all lanes together (edge line to edge line)."""
        r = self.road
        if r.directions == 1:
            return r.carriageway_width / 2
        return r.median / 2 + r.carriageway_width

    def lane_boundaries(self) -> list[float]:
        """World y of every lane boundary (edge and divider lines), sorted."""
        ys = set()
        for d in range(self.road.directions):
            lo, hi = self.carriageway_edges(d)
            ys.update(np.round(np.linspace(lo, hi, self.road.lanes + 1), 9).tolist())
        return sorted(ys)


def build_scene(road: RoadSpec, rng: np.random.Generator, lit_lamps: bool) -> tuple[np.ndarray, np.ndarray,
                                                                                      list[tuple[float, float]]]:
    """(ground layers in paint order, raised objects, lamp positions (x, y)) for the road."""
    lay = RoadLayout(road)
    x0, x1 = -road.behind - 50.0, road.length + 200.0
    hw = lay.half_width
    curve = road_curve(road)
    seg = 4.0 if curve is not None else 0.0
    ground, objects = MeshBuilder(seg=seg), MeshBuilder(seg=seg)
    lamps: list[tuple[float, float]] = []

    # far field: grass plane out to the horizon band, then fields
    far = 4000.0
    plain = MeshBuilder()  # the far grass plane is never bent
    plain.ground_rect(-far, far, -far, far, (0.33, 0.40, 0.22), MAT_GRASS)
    outer = hw + road.shoulder + road.verge
    # fields beyond the verges: alternating crop colours
    for side in (-1, 1):
        for i, xs in enumerate(np.arange(x0, x1, 120.0)):
            col = [(0.45, 0.42, 0.25), (0.30, 0.38, 0.20), (0.50, 0.47, 0.33)][int(rng.integers(0, 3))]
            y_a, y_b = sorted((side * (outer + 2.0), side * (outer + 2.0 + rng.uniform(80, 300))))
            ground.ground_rect(xs, xs + 120.0, y_a, y_b, col, MAT_GRASS)
    # gravel strip + shoulders + asphalt
    ground.ground_rect(x0, x1, -hw - road.shoulder - 0.8, hw + road.shoulder + 0.8, (0.42, 0.40, 0.37),
                       MAT_CONCRETE)
    ground.ground_rect(x0, x1, -hw - road.shoulder, hw + road.shoulder, tuple(road.surface), MAT_ASPHALT)
    if road.directions == 2 and road.median > 2.5:  # grass median
        m = road.median / 2 - 0.7
        ground.ground_rect(x0, x1, -m, m, (0.30, 0.38, 0.20), MAT_GRASS)

    # markings
    paint = (0.86, 0.86, 0.82)
    for d in range(road.directions):
        lo, hi = lay.carriageway_edges(d)
        ew = road.edge_line_width
        for y in (lo, hi):  # solid edge lines, inside the carriageway
            inner = y + ew / 2 if y == lo else y - ew / 2
            ground.ground_rect(x0, x1, inner - ew / 2, inner + ew / 2, paint, MAT_PAINT)
        period = road.dash + road.gap
        starts = np.arange(np.floor(x0 / period) * period, x1, period)
        for k in range(1, road.lanes):
            y = lo + k * road.lane_width
            n = len(starts)
            ground.ground_rects(starts, starts + road.dash, np.full(n, y - road.line_width / 2),
                                np.full(n, y + road.line_width / 2), paint, MAT_PAINT)

    # median barrier
    if road.directions == 2 and road.median_barrier and road.median >= 0.8:
        _concrete_barrier(objects, x0, x1, 0.0)

    # guard rails on the outer verges
    rail_y = hw + road.shoulder + 0.5
    if road.guard_rails:
        for side in (-1, 1):
            _guard_rail(objects, x0, x1, side * rail_y, side)

    # lamp posts
    if road.pole_spacing > 0:
        for side in (-1, 1):
            y = side * (rail_y + 1.0)
            for x in np.arange(x0 + rng.uniform(0, road.pole_spacing), x1, road.pole_spacing):
                _lamp_post(objects, x, y, side)
                lamps.append((float(x), float(y - side * 2.2)))

    # signs
    for _ in range(road.signs):
        side = rng.choice([-1, 1])
        x = rng.uniform(5, min(road.length, 250))
        _sign(objects, x, side * (rail_y + 2.0 + rng.uniform(0, 2)), rng)

    # trees
    for _ in range(road.trees):
        side = rng.choice([-1, 1])
        x = rng.uniform(x0, x1)
        y = side * (rail_y + 4.0 + rng.exponential(12.0))
        _tree(objects, x, y, rng)
    # distant tree lines and woods at the horizon (edges that are not traffic)
    for side in (-1, 1):
        for x in np.arange(-1500, 3500, 35.0):
            y = side * rng.uniform(250, 1200)
            h = rng.uniform(10, 22)
            g = rng.uniform(0.8, 1.2)
            objects.prism((x, y, 0), rng.uniform(12, 25), rng.uniform(9, 18), h, (0.13 * g, 0.20 * g, 0.10 * g),
                          MAT_FOLIAGE, sides=7)
    g, o = ground.array(), objects.array()
    if curve is not None:
        g, o = curve.bend(g), curve.bend(o)
        lamps = [(x, y + float(curve.offset(x))) for x, y in lamps]
    return np.concatenate([plain.array(), g]), o, lamps


def _concrete_barrier(m: MeshBuilder, x0: float, x1: float, y: float) -> None:
    # New Jersey profile approximated by a trapezoid
    col = (0.62, 0.61, 0.58)
    pts = [(-0.30, 0.0), (-0.20, 0.25), (-0.08, 0.80), (0.08, 0.80), (0.20, 0.25), (0.30, 0.0)]
    for (ya, za), (yb, zb) in zip(pts[:-1], pts[1:]):
        m.quad((x0, y + ya, za), (x0, y + yb, zb), (x1, y + yb, zb), (x1, y + ya, za), col, MAT_CONCRETE)


def _guard_rail(m: MeshBuilder, x0: float, x1: float, y: float, side: int) -> None:
    steel = (0.70, 0.72, 0.74)
    # W-beam face towards the road and a top lip
    face = -side * 0.0
    m.quad((x0, y + face, 0.45), (x1, y + face, 0.45), (x1, y + face, 0.78), (x0, y + face, 0.78), steel, MAT_METAL)
    if side > 0:
        m.quad((x1, y, 0.45), (x0, y, 0.45), (x0, y, 0.78), (x1, y, 0.78), steel, MAT_METAL)
    m.quad((x0, y - 0.1, 0.78), (x1, y - 0.1, 0.78), (x1, y + 0.1, 0.78), (x0, y + 0.1, 0.78), steel, MAT_METAL)
    for x in np.arange(x0, x1, 4.0):
        m.box((x, y + side * 0.15, 0.0), (0.12, 0.12, 0.75), (0.45, 0.46, 0.47), MAT_METAL)


def _lamp_post(m: MeshBuilder, x: float, y: float, side: int) -> None:
    grey = (0.55, 0.56, 0.57)
    m.prism((x, y, 0), 0.12, 0.08, 10.0, grey, MAT_METAL, sides=6)
    m.box((x, y - side * 1.1, 9.9), (0.12, 2.3, 0.1), grey, MAT_METAL)
    m.box((x, y - side * 2.2, 9.75), (0.7, 0.35, 0.18), (0.35, 0.35, 0.36), MAT_METAL)
    m.box((x, y - side * 2.2, 9.72), (0.6, 0.3, 0.03), (1.0, 0.85, 0.6), MAT_LAMP)


def _sign(m: MeshBuilder, x: float, y: float, rng: np.random.Generator) -> None:
    m.prism((x, y, 0), 0.05, 0.05, 2.2, (0.6, 0.6, 0.6), MAT_METAL, sides=5)
    kind = int(rng.integers(0, 3))
    if kind == 0:  # blue information board facing the traffic
        m.box((x - 0.05, y, 2.0), (0.05, 2.4, 1.4), (0.10, 0.25, 0.60), MAT_SIGN)
    elif kind == 1:  # white square with red border
        m.box((x - 0.05, y, 2.0), (0.05, 0.9, 0.9), (0.80, 0.12, 0.10), MAT_SIGN)
        m.box((x - 0.08, y, 2.08), (0.02, 0.72, 0.74), (0.92, 0.92, 0.90), MAT_SIGN)
    else:  # yellow diamond-ish board
        m.box((x - 0.05, y, 2.0), (0.05, 0.8, 0.8), (0.90, 0.75, 0.10), MAT_SIGN)


def _tree(m: MeshBuilder, x: float, y: float, rng: np.random.Generator) -> None:
    """A deciduous tree: trunk and a crown of a few irregular stacked frusta, or a conifer."""
    h = rng.uniform(6, 14)
    g = rng.uniform(0.75, 1.25)
    m.prism((x, y, 0), 0.18, 0.12, h * 0.45, (0.28, 0.22, 0.16), MAT_PLAIN, sides=5, cap=False)
    if rng.random() < 0.3:  # conifer
        green = (0.10 * g, 0.19 * g, 0.10 * g)
        r = h * 0.22
        for k in range(3):
            z = h * (0.25 + 0.22 * k)
            m.prism((x, y, z), r * (1 - 0.25 * k), 0.0, h * 0.35, green, MAT_FOLIAGE, sides=8)
        return
    green = (0.17 * g, 0.27 * g, 0.11 * g)
    r = h * rng.uniform(0.22, 0.32)
    z0 = h * 0.35
    for k in range(3):
        dx, dy = rng.normal(0, r * 0.15, 2)
        rr = r * (0.75 + 0.25 * np.sin(np.pi * (k + 0.5) / 3)) * rng.uniform(0.9, 1.1)
        m.prism((x + dx, y + dy, z0 + k * h * 0.2), rr * 0.8, rr, h * 0.2, green, MAT_FOLIAGE, sides=9, cap=False)
    m.prism((x, y, z0 + 3 * h * 0.2), r * 0.9, r * 0.2, h * 0.12, green, MAT_FOLIAGE, sides=9)
