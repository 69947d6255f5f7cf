"""Rendering of the synthetic scenes: textured table and floor, shaded objects, depth.

Depth convention (the one of the GG-CNN-processed Cornell `d.tiff`): float32 distance from the
camera in metres. The table is a tilted plane, about 0.8 m away at the bottom row and about 1.3 m
at row 150; the floor beyond the table is farther. Objects stand on the table, so they are CLOSER
to the camera than the table: their depth is SMALLER than the table's. The table plane is
`1 / depth = a + b * y + c * x` at pixel centres (x, y) = (column + 0.5, row + 0.5); every object
pixel is at least MIN_OBJECT_HEIGHT_M nearer than that plane and every other pixel is not nearer.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from kosmos_jax.sources.synthetic.objects import METRES_PER_PIXEL, ObjectSpec, PartShape

HEIGHT, WIDTH = 480, 640
MIN_OBJECT_HEIGHT_M = 0.008
DEPTH_NOISE_M = 0.0004  # amplitude of the smooth noise on the depth image
TABLE_KINDS = ("foam", "wood", "tiles", "cloth", "granite")
FLOOR_KINDS = ("carpet", "concrete")


@dataclasses.dataclass(frozen=True)
class Background:
    """One background (a Cornell `pcdb_XXXX`): the empty table, shared by several photos."""

    name: str
    rgb: np.ndarray  # [H, W, 3] float32, 0..255, illumination included
    depth: np.ndarray  # [H, W] float32 metres
    table_mask: np.ndarray  # [H, W] bool
    table_inverse_depth: tuple[float, float, float]  # (a, b, c): 1/depth = a + b*y + c*x
    illumination: np.ndarray  # [H, W] float32, multiplies the objects' colours too
    light: np.ndarray  # [3] unit vector towards the light (x right, y down, z to the camera)
    kind: str


def value_noise(rng, shape, cells, interpolation=cv2.INTER_CUBIC):
    """Smooth noise of about `cells` blobs along the longer side, roughly in [-1, 1]."""
    h, w = shape
    gh, gw = max(2, round(cells * h / max(h, w))), max(2, round(cells * w / max(h, w)))
    grid = rng.uniform(-1, 1, (gh + 1, gw + 1)).astype(np.float32)
    return cv2.resize(grid, (w, h), interpolation=interpolation)


def fractal_noise(rng, shape, cells=4, octaves=4):
    total = np.zeros(shape, np.float32)
    for octave in range(octaves):
        total += value_noise(rng, shape, cells * 2**octave) * 0.5**octave
    return total / 1.9


def _mix(a, b, t):
    a, b = np.asarray(a, np.float32), np.asarray(b, np.float32)
    return a + (b - a) * np.clip(t, 0, 1)[..., None]


def _muted(colour, keep=0.55):
    grey = colour.mean()
    return grey + keep * (colour - grey)


def texture(rng, kind, shape=(HEIGHT, WIDTH)):
    """[H, W, 3] float32 RGB 0..255 of a surface `kind`."""
    h, w = shape
    fine = value_noise(rng, shape, max(h, w) / 2, cv2.INTER_LINEAR)
    if kind == "foam":
        base = rng.uniform(215, 245, 3) * np.array([1.0, 0.99, 0.97])
        img = base + (8 * fractal_noise(rng, shape, 3) + 3 * fine)[..., None]
    elif kind == "wood":
        light = np.array(rng.choice([[196, 150, 100], [170, 120, 75], [210, 175, 130]]), np.float32)
        dark = light * rng.uniform(0.55, 0.7)
        size = int(math.hypot(h, w)) + 2
        y, x = np.mgrid[0:size, 0:size].astype(np.float32)
        warp = fractal_noise(rng, (size, size), 2, 3) * rng.uniform(0.5, 1.0)
        streak = cv2.resize(rng.uniform(-1, 1, (size // 2, 10)).astype(np.float32), (size, size))
        rings = np.sin(2 * math.pi * (y / rng.uniform(9, 20) + warp)) * 0.5 + 0.5
        wood = _mix(dark, light, rings ** 2 * 0.6 + 0.25 * streak + 0.3)
        turn = cv2.getRotationMatrix2D((size / 2, size / 2), rng.uniform(-90, 90), 1.0)
        turn[:, 2] -= [(size - w) / 2, (size - h) / 2]
        img = cv2.warpAffine(wood, turn, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        img += (4 * fine)[..., None]
    elif kind == "tiles":
        a, b = _muted(rng.uniform(60, 230, 3)), _muted(rng.uniform(60, 230, 3))
        step = rng.uniform(28, 60)
        y, x = np.mgrid[0:h, 0:w].astype(np.float32)
        checker = (np.floor(x / step) + np.floor(y / step)) % 2
        grout = ((x % step) < 2) | ((y % step) < 2)
        img = _mix(a, b, checker)
        img[grout] *= 0.6
        img += (8 * fractal_noise(rng, shape, 8) + 4 * fine)[..., None]
    elif kind == "cloth":
        a, b = _muted(rng.uniform(40, 220, 3)), _muted(rng.uniform(40, 220, 3))
        y, x = np.mgrid[0:h, 0:w].astype(np.float32)
        px, py = rng.uniform(8, 24, 2)
        plaid = 0.5 * (np.sin(2 * math.pi * x / px) > 0) + 0.5 * (np.sin(2 * math.pi * y / py) > 0)
        img = _mix(a, b, plaid) + (10 * fine + 5 * fractal_noise(rng, shape, 6))[..., None]
    elif kind == "granite":
        base = rng.uniform(90, 200, 3)
        img = base + (18 * fine + 12 * fractal_noise(rng, shape, 10))[..., None]
        img += (25 * (value_noise(rng, shape, max(h, w), cv2.INTER_NEAREST) > 0.85))[..., None]
    elif kind == "carpet":
        base = np.array(rng.choice([[95, 80, 65], [70, 70, 75], [110, 95, 80], [60, 55, 70]]), np.float32)
        img = base + (30 * value_noise(rng, shape, max(h, w), cv2.INTER_NEAREST) + 8 * fine)[..., None]
    elif kind == "concrete":
        base = rng.uniform(110, 160) * np.ones(3, np.float32)
        img = base + (14 * fractal_noise(rng, shape, 6) + 6 * fine)[..., None]
    else:
        raise ValueError(f"unknown texture kind {kind!r}")
    return img.astype(np.float32)


def pixel_grid(shape=(HEIGHT, WIDTH)):
    """Pixel-centre coordinates x, y, each [H, W] float64."""
    y, x = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    return x + 0.5, y + 0.5


def table_depth(inverse_depth, shape=(HEIGHT, WIDTH)):
    a, b, c = inverse_depth
    x, y = pixel_grid(shape)
    return 1.0 / (a + b * y + c * x)


def make_background(rng: np.random.Generator, name: str) -> Background:
    """A table (textured, tilted plane) in front of a farther floor, with smooth lighting."""
    kind = str(rng.choice(TABLE_KINDS))
    top = rng.uniform(70, 140)
    tilt = rng.uniform(-15, 15)
    corners = np.array([[rng.uniform(0, 80), top - tilt], [rng.uniform(560, 640), top + tilt],
                        [rng.uniform(620, 720), 520], [rng.uniform(-80, 20), 520]])
    table_mask = rasterise(corners, (), (HEIGHT, WIDTH))

    z_bottom, z_far = rng.uniform(0.78, 0.88), rng.uniform(1.2, 1.35)
    c = rng.uniform(-1.5e-4, 1.5e-4)
    b = (1 / z_bottom - 1 / z_far) / (479.5 - 150.0)
    a = 1 / z_bottom - b * 479.5 - c * 320.0
    plane = table_depth((a, b, c)).astype(np.float32)
    # The floor is 0.3-0.5 m below the table but, like the real files, no farther than about 2 m.
    floor_depth = np.maximum(np.minimum(plane + rng.uniform(0.3, 0.5), rng.uniform(1.95, 2.05)), plane + 0.05)
    depth = np.where(table_mask, plane, floor_depth).astype(np.float32)

    table_rgb = texture(rng, kind)
    floor_rgb = texture(rng, str(rng.choice(FLOOR_KINDS)))
    rgb = np.where(table_mask[..., None], table_rgb, floor_rgb)

    azimuth = rng.uniform(0, 2 * math.pi)
    elevation = rng.uniform(0.9, 1.3)
    light = np.array([math.cos(azimuth) * math.cos(elevation), math.sin(azimuth) * math.cos(elevation),
                      math.sin(elevation)])
    x, y = pixel_grid()
    gradient = 1 + 0.12 * ((x - 320) / 320 * light[0] + (y - 240) / 240 * light[1])
    vignette = 1 - 0.18 * (((x - 320) / 400) ** 2 + ((y - 240) / 300) ** 2)
    illumination = (gradient * vignette * rng.uniform(0.9, 1.05)).astype(np.float32)
    return Background(name=name, rgb=rgb * illumination[..., None], depth=depth, table_mask=table_mask,
                      table_inverse_depth=(float(a), float(b), float(c)), illumination=illumination,
                      light=light, kind=kind)


def rasterise(shell, holes, shape, offset=(0.0, 0.0)) -> np.ndarray:
    """Bool mask of the pixels whose CENTRES lie in the polygon minus its holes.

    cv2 puts pixel (col, row) at the point (col, row); our pixel centres are at +0.5, hence the
    shift. `offset` is the (x, y) of the mask's top-left pixel corner in photo coordinates.
    """
    mask = np.zeros(shape, np.uint8)
    scale = 16  # cv2 fixed-point with shift=4: sub-pixel vertices

    def points(poly):
        return np.round((np.asarray(poly) - np.asarray(offset) - 0.5) * scale).astype(np.int32)

    cv2.fillPoly(mask, [points(shell)], 1, lineType=cv2.LINE_8, shift=4)
    for hole in holes:
        cv2.fillPoly(mask, [points(hole)], 0, lineType=cv2.LINE_8, shift=4)
    return mask.astype(bool)


def _part_relief_px(mask: np.ndarray, part: PartShape) -> np.ndarray:
    """Height above the part's outline, in pixels: a cylinder/sphere cap or a small bevel."""
    dist = cv2.distanceTransform(np.pad(mask, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]
    if part.round_profile:
        radius = max(float(dist.max()), 1.0)
        return np.sqrt(np.clip(dist * (2 * radius - dist), 0, None))
    return np.minimum(dist, 3.0) * 0.5


@dataclasses.dataclass(frozen=True)
class Rendered:
    rgb: np.ndarray  # [H, W, 3] uint8
    depth: np.ndarray  # [H, W] float32
    object_mask: np.ndarray  # [H, W] bool
    part_masks: tuple[np.ndarray, ...]  # [H, W] bool per part, in spec.parts order


def render(rng: np.random.Generator, background: Background, spec: ObjectSpec) -> Rendered:
    """Draw the placed object `spec` on `background`: colour, shading, shadow, depth, noise."""
    every = np.concatenate([p.shell for p in spec.parts])
    pad = 24
    x0 = int(max(0, math.floor(every[:, 0].min()) - pad))
    x1 = int(min(WIDTH, math.ceil(every[:, 0].max()) + pad))
    y0 = int(max(0, math.floor(every[:, 1].min()) - pad))
    y1 = int(min(HEIGHT, math.ceil(every[:, 1].max()) + pad))
    box = (y1 - y0, x1 - x0)
    origin = (float(x0), float(y0))

    masks, relief_px, height_m = [], np.zeros(box, np.float32), np.zeros(box, np.float32)
    albedo = np.zeros(box + (3,), np.float32)
    shiny = np.zeros(box, bool)
    for part in spec.parts:
        mask = rasterise(part.shell, part.holes, box, origin)
        relief = _part_relief_px(mask, part)
        part_relief_m = relief * (METRES_PER_PIXEL if part.round_profile else 0.001)
        part_height = np.where(mask, part.base_m + part_relief_m, 0).astype(np.float32)
        take = mask & (part_height >= height_m)
        height_m[take] = part_height[take]
        relief_px[take] = relief[take]
        tint = 1 + 0.05 * value_noise(rng, box, 6)
        albedo[take] = np.asarray(part.colour, np.float32) * tint[take][:, None]
        shiny[take] = part.shiny
        masks.append(mask)
    obj = np.any(masks, axis=0)
    for decal in spec.decals:
        paint = rasterise(decal.shell, (), box, origin) & obj
        albedo[paint] = decal.colour
        if decal.height_m is not None:
            height_m[paint] = max(decal.height_m, MIN_OBJECT_HEIGHT_M + 0.002)
            relief_px[paint] = 0

    # Lambertian shading from the relief's normals, plus a highlight on shiny parts.
    gy, gx = np.gradient(cv2.GaussianBlur(relief_px, (0, 0), 1.5))  # blur: no creases on the medial axis
    normal = np.stack([-gx, -gy, np.ones_like(gx)], -1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    lambert = np.clip(normal @ background.light.astype(np.float32), 0, 1)
    half = background.light + np.array([0, 0, 1.0])
    half = (half / np.linalg.norm(half)).astype(np.float32)
    highlight = np.where(shiny, 140 * np.clip(normal @ half, 0, 1) ** 40, 0)
    lit = albedo * (0.4 + 0.7 * lambert)[..., None] + highlight[..., None]
    lit *= background.illumination[y0:y1, x0:x1, None]

    # Soft shadow cast away from the light, then the object over it with softened edges.
    region = background.rgb[y0:y1, x0:x1].copy()
    reach = 6 + 40 * float(np.clip(height_m.max(), 0, 0.12))
    lx, ly, lz = background.light
    shift = np.float32([[1, 0, -lx / lz * reach], [0, 1, -ly / lz * reach]])
    shadow = cv2.warpAffine(obj.astype(np.float32), shift, (box[1], box[0]))
    shadow = cv2.GaussianBlur(shadow, (0, 0), 4 + reach / 4)
    region *= (1 - 0.45 * shadow)[..., None]
    alpha = cv2.GaussianBlur(obj.astype(np.float32), (3, 3), 0.6) * obj
    region = region * (1 - alpha[..., None]) + lit * alpha[..., None]

    rgb = background.rgb.copy()
    rgb[y0:y1, x0:x1] = region
    rgb = cv2.GaussianBlur(rgb, (0, 0), 0.6)  # the camera's own softness
    rgb += rng.standard_normal(rgb.shape, dtype=np.float32) * 2.5
    rgb_u8 = np.clip(np.round(rgb), 0, 255).astype(np.uint8)

    depth = background.depth.copy()
    plane = table_depth(background.table_inverse_depth)[y0:y1, x0:x1].astype(np.float32)
    lifted = np.maximum(height_m, MIN_OBJECT_HEIGHT_M)
    depth[y0:y1, x0:x1] = np.where(obj, plane - lifted, depth[y0:y1, x0:x1])
    depth += DEPTH_NOISE_M * value_noise(rng, (HEIGHT, WIDTH), 12)

    def full(mask):
        out = np.zeros((HEIGHT, WIDTH), bool)
        out[y0:y1, x0:x1] = mask
        return out

    return Rendered(rgb=rgb_u8, depth=depth.astype(np.float32), object_mask=full(obj),
                    part_masks=tuple(full(m) for m in masks))
