"""The geometry terrains are built from: sizes, the floor, boxes, height fields, contacts. Pure numpy.

World frame: x forward (the walking direction), y left, z up, metres; the floor is ``z = 0`` and the
robot starts at the origin. :mod:`hexapod_sim.physics.terrain` names the terrains made of these parts.

Sizes the paper does not state (tread depth, field extents, slopes, roughness) are project
nominal values ([N]) named once below. Blocks and steps are boxes (cheap, exact collisions); the
rough terrain is a MuJoCo height field. :meth:`Terrain.height_at` gives the true surface height for
evaluation (spawn height, foot clearance) and is never used by a controller.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

# ----------------------------------------------------------------------------- nominal sizes [N]
FLOOR_HALF_SIZE_M = 5.0              # floor plane half extent (rendering only; a plane is infinite)
START_PAD_HALF_M = 0.35              # flat area around the origin where the robot stands at start
BLOCK_SIZE_M = 0.10                  # [P] Fig. 10: wooden blocks of 10 x 10 cm
BLOCK_HEIGHT_RANGE_M = (0.0, 0.06)   # top height of a block above the floor (modest: the robot is ~13 cm tall)
BLOCK_MAX_SLOPE_RAD = math.radians(10.0)
BLOCK_THICKNESS_M = 0.10             # boxes reach below the floor, so a tilted top never shows a gap
BLOCK_FIELD_X_M = (0.40, 1.20)       # blocks terrain: x extent of the block field
FIELD_HALF_WIDTH_M = 0.40            # y extent (+-) of blocks, stairs and rough field
STEP_RISE_M = 0.04                   # [P] Fig. 10: stairs with 4 cm steps
STEP_TREAD_M = 0.20                  # tread depth of one step
STEP_COUNT = 3                       # steps up, then a landing of LANDING_DEPTH_M
LANDING_DEPTH_M = 1.00              # long enough that the front feet still stand on it at the course end
STAIRS_START_X_M = 0.45              # stairs terrain: x of the first riser
ROUGH_HALF_SIZE_M = (1.5, 1.0)       # rough terrain: height field half extents (x, y)
ROUGH_CELL_M = 0.02                  # height-field resolution
ROUGH_AMPLITUDE_M = 0.04             # peak-to-peak height of the rough terrain
ROUGH_CORRELATION_M = 0.06           # smoothing length of the random field
MOCKUP_BLOCKS_X_M = (0.60, 1.40)     # mockup: flat, then blocks, ...
MOCKUP_STAIRS_X_M = 1.60             # ... then the first riser of the stairs
# where a walk over the mockup ends (the trunk's x): on the landing, whose far edge is a drop of three
# steps; the front feet reach about 0.3 m ahead of the trunk (with 0.6 m of landing, robots that got
# there within a minute stepped off its edge)
MOCKUP_COURSE_END_M = 2.60

WOOD_RGBA = (0.72, 0.55, 0.35, 1.0)
WOOD_DARK_RGBA = (0.60, 0.44, 0.27, 1.0)
GROUND_RGBA = (0.35, 0.38, 0.42, 1.0)


class TerrainError(ValueError):
    """Unknown terrain name or bad terrain parameters (the message says which)."""


@dataclass(frozen=True)
class Contact:
    """Contact of a terrain geom with a foot, overriding the defaults (MuJoCo geom ``priority``):
    sliding friction, and ``solref`` / ``solimp`` (compliance) where given."""

    friction: float = 1.0
    solref: tuple[float, float] | None = None
    solimp: tuple[float, float, float, float, float] | None = None

    def mjcf_attrs(self) -> str:
        out = f'priority="1" friction="{self.friction:.6g} 0.005 0.0001"'
        if self.solref is not None:
            out += f' solref="{_fmt(self.solref)}"'
        if self.solimp is not None:
            out += f' solimp="{_fmt(self.solimp)}"'
        return out


@dataclass(frozen=True)
class Box:
    """A box geom: centre [m], half sizes [m], rotation matrix (box frame -> world)."""

    name: str
    center_m: tuple[float, float, float]
    half_size_m: tuple[float, float, float]
    rotation: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    rgba: tuple[float, float, float, float] = WOOD_RGBA
    contact: Contact | None = None      # None: the terrain class's defaults

    def quat(self) -> tuple[float, float, float, float]:
        return _mat_to_quat(np.array(self.rotation))

    def top_height(self, x, y) -> np.ndarray:
        """Highest point of the box above (x, y), -inf where the vertical line misses it.

        Exact for a rotated box (a tilted block leans its sides over its neighbours' footprints):
        intersection of the downward vertical line with the box's three slabs.
        """
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        R = np.array(self.rotation)
        c = np.array(self.center_m)
        h = np.array(self.half_size_m)
        top = c[2] + np.abs(R[2, :]) @ h + 1.0          # start above the box
        o = np.stack([x - c[0], y - c[1], np.full_like(x, top - c[2])], axis=-1) @ R   # box frame
        dl = -R[2, :]                                     # direction (0, 0, -1) in the box frame
        t_in = np.zeros(x.shape)
        t_out = np.full(x.shape, np.inf)
        hit = np.ones(x.shape, dtype=bool)
        for i in range(3):
            if abs(dl[i]) < 1e-12:                        # parallel to this slab
                hit &= np.abs(o[..., i]) <= h[i]
                continue
            t1 = (-h[i] - o[..., i]) / dl[i]
            t2 = (h[i] - o[..., i]) / dl[i]
            t_in = np.maximum(t_in, np.minimum(t1, t2))
            t_out = np.minimum(t_out, np.maximum(t1, t2))
        hit &= t_in <= t_out
        return np.where(hit, top - t_in, -np.inf)


@dataclass(frozen=True)
class HeightField:
    """A MuJoCo height field: ``elevation`` (nrow, ncol) in metres above ``base_z_m``; rows along y."""

    name: str
    center_m: tuple[float, float]
    half_size_m: tuple[float, float]
    elevation_m: np.ndarray = field(repr=False)
    base_z_m: float = 0.0

    def height_at(self, x, y) -> np.ndarray:
        """Bilinear interpolation of the grid (MuJoCo triangulates each cell: within 1 mm here)."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        nrow, ncol = self.elevation_m.shape
        u = (x - self.center_m[0] + self.half_size_m[0]) / (2 * self.half_size_m[0]) * (ncol - 1)
        v = (y - self.center_m[1] + self.half_size_m[1]) / (2 * self.half_size_m[1]) * (nrow - 1)
        inside = (u >= 0) & (u <= ncol - 1) & (v >= 0) & (v <= nrow - 1)
        u = np.clip(u, 0, ncol - 1)
        v = np.clip(v, 0, nrow - 1)
        i0 = np.minimum(np.floor(v).astype(int), nrow - 2)
        j0 = np.minimum(np.floor(u).astype(int), ncol - 2)
        fv, fu = v - i0, u - j0
        e = self.elevation_m
        h = ((1 - fv) * ((1 - fu) * e[i0, j0] + fu * e[i0, j0 + 1])
             + fv * ((1 - fu) * e[i0 + 1, j0] + fu * e[i0 + 1, j0 + 1]))
        return np.where(inside, self.base_z_m + h, -np.inf)


@dataclass(frozen=True)
class Terrain:
    """A named terrain: the floor plane plus boxes and an optional height field."""

    name: str
    seed: int
    boxes: tuple[Box, ...] = ()
    hfield: HeightField | None = None
    floor_z_m: float = 0.0              # height of the floor plane (courses lay slabs over a lower floor)


    def height_at(self, x, y) -> np.ndarray:
        """True surface height [m] at world (x, y) (vectorised): the highest of floor, boxes, field."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        h = np.full(np.broadcast(x, y).shape, float(self.floor_z_m))
        for b in self.boxes:
            h = np.maximum(h, b.top_height(x, y))
        if self.hfield is not None:
            h = np.maximum(h, self.hfield.height_at(x, y))
        return h

    # -- MJCF fragments
    def mjcf_assets(self) -> str:
        parts = ['<texture name="grid" type="2d" builtin="checker" rgb1="0.32 0.35 0.39" rgb2="0.38 0.41 0.45" '
                 'width="512" height="512" mark="edge" markrgb="0.5 0.5 0.5"/>',
                 '<material name="ground" texture="grid" texrepeat="10 10" reflectance="0.05"/>']
        if self.hfield is not None:
            hf = self.hfield
            e = hf.elevation_m
            span = float(e.max() - e.min())
            norm = (e - e.min()) / span if span > 0 else np.zeros_like(e)
            # MuJoCo's elevation rows run from +y to -y; ours from -y to +y
            vals = ' '.join(f'{v:.5f}' for v in norm[::-1].ravel())
            nrow, ncol = e.shape
            parts.append(f'<hfield name="{hf.name}" nrow="{nrow}" ncol="{ncol}" '
                         f'size="{hf.half_size_m[0]:.6g} {hf.half_size_m[1]:.6g} {max(span, 1e-6):.6g} 0.01" '
                         f'elevation="{vals}"/>')
        return '\n    '.join(parts)

    def mjcf_geoms(self) -> str:
        cls = 'class="terrain"'
        floor_pos = f' pos="0 0 {self.floor_z_m:.6g}"' if self.floor_z_m else ''
        parts = [f'<geom name="floor" type="plane" size="{FLOOR_HALF_SIZE_M} {FLOOR_HALF_SIZE_M} 0.05"{floor_pos} '
                 f'material="ground" {cls}/>']
        for b in self.boxes:
            q = b.quat()
            contact = f' {b.contact.mjcf_attrs()}' if b.contact is not None else ''
            parts.append(f'<geom name="{b.name}" type="box" {cls} pos="{_fmt(b.center_m)}" '
                         f'size="{_fmt(b.half_size_m)}" quat="{_fmt(q)}" rgba="{_fmt(b.rgba)}"{contact}/>')
        if self.hfield is not None:
            hf = self.hfield
            zmin = float(hf.elevation_m.min()) + hf.base_z_m
            parts.append(f'<geom name="{hf.name}" type="hfield" hfield="{hf.name}" {cls} '
                         f'pos="{hf.center_m[0]:.6g} {hf.center_m[1]:.6g} {zmin:.6g}" rgba="{_fmt(WOOD_RGBA)}"/>')
        return '\n    '.join(parts)


# ----------------------------------------------------------------------------- generators
def _fmt(v) -> str:
    return ' '.join(f'{float(x):.10g}' for x in v)


def _mat_to_quat(R: np.ndarray) -> tuple[float, float, float, float]:
    """Rotation matrix -> unit quaternion (w, x, y, z), w >= 0."""
    t = np.trace(R)
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        q = (0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s)
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = ((R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s)
    elif R[1, 1] > R[2, 2]:
        s = math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = ((R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s)
    else:
        s = math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = ((R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s)
    q = np.array(q)
    q /= np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    return tuple(float(v) for v in q)


def _rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def block_field(rng: np.random.Generator, x_range, half_width: float = FIELD_HALF_WIDTH_M,
                heights=BLOCK_HEIGHT_RANGE_M, max_slope_rad: float = BLOCK_MAX_SLOPE_RAD,
                prefix: str = 'block') -> tuple[Box, ...]:
    """A grid of 10 x 10 cm blocks with random top height and random slope (tilt about x or y).

    The top face of each block is centred at the drawn height and tilted by the drawn slope; the
    box extends ``BLOCK_THICKNESS_M`` down so that it always meets the floor.
    """
    x0, x1 = x_range
    if not (x1 > x0) or half_width <= 0 or not (0.0 <= heights[0] <= heights[1]) or max_slope_rad < 0:
        raise TerrainError(f'bad block field: x_range={x_range}, half_width={half_width}, heights={heights}, '
                           f'max_slope_rad={max_slope_rad}')
    nx = int(round((x1 - x0) / BLOCK_SIZE_M))
    ny = int(round(2 * half_width / BLOCK_SIZE_M))
    half = BLOCK_SIZE_M / 2
    boxes = []
    for i in range(nx):
        for j in range(ny):
            h = float(rng.uniform(*heights))
            slope = float(rng.uniform(-max_slope_rad, max_slope_rad))
            R = _rot_y(slope) if rng.random() < 0.5 else _rot_x(slope)
            top = np.array([x0 + (i + 0.5) * BLOCK_SIZE_M, -half_width + (j + 0.5) * BLOCK_SIZE_M, h])
            # shrink the footprint by a hair so neighbouring tilted blocks do not overlap visually
            hs = (half * 0.995, half * 0.995, BLOCK_THICKNESS_M / 2)
            centre = top - R[:, 2] * hs[2]
            rgba = WOOD_RGBA if (i + j) % 2 == 0 else WOOD_DARK_RGBA
            boxes.append(Box(f'{prefix}_{i}_{j}', tuple(centre), hs, tuple(map(tuple, R)), rgba))
    return tuple(boxes)


def stair_flight(x_start: float, half_width: float = FIELD_HALF_WIDTH_M, rise: float = STEP_RISE_M,
                 tread: float = STEP_TREAD_M, count: int = STEP_COUNT, landing: float = LANDING_DEPTH_M,
                 prefix: str = 'step') -> tuple[Box, ...]:
    """``count`` steps of ``rise`` up along +x starting at ``x_start``; the last one is a landing."""
    if rise <= 0 or tread <= 0 or count < 1 or landing <= 0:
        raise TerrainError(f'bad stairs: rise={rise}, tread={tread}, count={count}, landing={landing}')
    boxes = []
    for k in range(count):
        depth = landing if k == count - 1 else tread
        top = rise * (k + 1)
        x_lo = x_start + k * tread
        boxes.append(Box(f'{prefix}_{k}', (x_lo + depth / 2, 0.0, top / 2), (depth / 2, half_width, top / 2),
                         rgba=WOOD_RGBA if k % 2 == 0 else WOOD_DARK_RGBA))
    return tuple(boxes)


def rough_field(rng: np.random.Generator, half_size=ROUGH_HALF_SIZE_M, cell: float = ROUGH_CELL_M,
                amplitude: float = ROUGH_AMPLITUDE_M, correlation: float = ROUGH_CORRELATION_M,
                pad_half: float = START_PAD_HALF_M) -> HeightField:
    """Smoothed Gaussian noise scaled to ``amplitude`` peak to peak (heights in [0, amplitude]).

    The start pad around the origin is blended to height 0 so the robot starts on level ground.
    """
    if amplitude <= 0 or cell <= 0 or correlation <= 0:
        raise TerrainError(f'bad rough terrain: amplitude={amplitude}, cell={cell}, correlation={correlation}')
    ncol = int(round(2 * half_size[0] / cell)) + 1
    nrow = int(round(2 * half_size[1] / cell)) + 1
    noise = rng.standard_normal((nrow, ncol))
    # separable Gaussian smoothing (numpy only)
    sigma = correlation / cell
    r = int(math.ceil(3 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    sm = np.apply_along_axis(lambda v: np.convolve(np.pad(v, r, mode='wrap'), k, mode='valid'), 1, noise)
    sm = np.apply_along_axis(lambda v: np.convolve(np.pad(v, r, mode='wrap'), k, mode='valid'), 0, sm)
    sm = (sm - sm.min()) / (sm.max() - sm.min()) * amplitude
    xs = np.linspace(-half_size[0], half_size[0], ncol)
    ys = np.linspace(-half_size[1], half_size[1], nrow)
    X, Y = np.meshgrid(xs, ys)
    d = np.maximum(np.abs(X), np.abs(Y))           # square start pad, blended over 10 cm
    w = np.clip((d - pad_half) / 0.10, 0.0, 1.0)
    elev = sm * w
    return HeightField('rough', (0.0, 0.0), tuple(half_size), elev, 0.0)
