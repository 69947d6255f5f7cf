"""Grasp rectangles for the synthetic scenes, sampled against the rendered object masks.

A positive grasp is antipodal across a part's narrow axis: its centre lies on the part, its
opening axis (p0 -> p1, DESIGN.md section 2) crosses the part, the opening is a little wider than
the object along that axis, and both jaws (edges p0-p3 and p1-p2) lie off the object, so the
gripper closes on the part and on nothing else. A negative is clearly not graspable: its centre
is off the object ("off"), or a jaw lands on the object because the rectangle lies along the
part's long axis ("along") or opens narrower than the part ("narrow").
The margins (CLEARANCE_PX) keep both verdicts true when the mask is rebuilt from the depth file.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from kosmos_jax import geometry
from kosmos_jax.sources.synthetic.objects import PartShape

MAX_OPENING_PX = 100.0
OPENING_MARGIN_PX = (8.0, 18.0)  # total extra opening beyond the object, both sides together
CLEARANCE_PX = 2
EDGE_PX = 2.0  # rectangles stay this far inside the photo
STEP_PX = 0.25
NEGATIVE_KINDS = ("along", "narrow", "off")


def inside(mask: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Whether each (x, y) point falls in a True pixel (pixel (c, r) covers [c, c+1) x [r, r+1))."""
    points = np.asarray(points, np.float64)
    cols, rows = np.floor(points[..., 0]).astype(int), np.floor(points[..., 1]).astype(int)
    ok = (rows >= 0) & (rows < mask.shape[0]) & (cols >= 0) & (cols < mask.shape[1])
    out = np.zeros(points.shape[:-1], bool)
    out[ok] = mask[rows[ok], cols[ok]]
    return out


def chord(mask, point, direction, limit=160.0):
    """Distances (back, forward) from `point` to where the run of mask pixels along +-direction ends.

    None when `point` is not on the mask. The chord through the point is back + forward long.
    """
    if not inside(mask, point[None])[0]:
        return None
    steps = np.arange(1, int(limit / STEP_PX) + 1) * STEP_PX
    out = []
    for sign in (-1.0, 1.0):
        hits = inside(mask, point + sign * steps[:, None] * direction)
        first_miss = int(np.argmin(hits)) if not hits.all() else len(steps)
        out.append(first_miss * STEP_PX)
    return out[0], out[1]


def jaw_points(grasp: np.ndarray, spacing: float = 0.5) -> np.ndarray:
    """[2, K, 2] points along the two jaws: edge p0-p3 and edge p1-p2."""
    corners = geometry.grasps_to_corners(np.asarray(grasp, np.float64))
    k = max(2, int(math.ceil(grasp[3] / spacing)) + 1)
    t = np.linspace(0, 1, k)[:, None]
    first = corners[0] + t * (corners[3] - corners[0])
    second = corners[1] + t * (corners[2] - corners[1])
    return np.stack([first, second])


def in_photo(grasp, shape) -> bool:
    corners = geometry.grasps_to_corners(np.asarray(grasp, np.float64))
    h, w = shape
    return bool(np.all((corners[:, 0] >= EDGE_PX) & (corners[:, 0] <= w - EDGE_PX)
                       & (corners[:, 1] >= EDGE_PX) & (corners[:, 1] <= h - EDGE_PX)))


def make_grasp(centre, direction, opening, jaw):
    theta = geometry.normalize_angle(math.atan2(-direction[1], direction[0]))
    return np.array([centre[0], centre[1], opening, jaw, theta])


def point_on_spine(rng, spine):
    """A random point of the polyline and its unit tangent there."""
    if len(spine) == 1:
        return spine[0].copy(), np.array([1.0, 0.0])
    lengths = np.linalg.norm(np.diff(spine, axis=0), axis=-1)
    at = rng.uniform(0, lengths.sum())
    i = min(int(np.searchsorted(np.cumsum(lengths), at)), len(lengths) - 1)
    t = (at - lengths[:i].sum()) / max(lengths[i], 1e-9)
    tangent = (spine[i + 1] - spine[i]) / max(lengths[i], 1e-9)
    return spine[i] + t * (spine[i + 1] - spine[i]), tangent


def across(rng, part, tangent):
    """The opening direction for a part: across its long axis, a few degrees of jitter."""
    if part.isotropic:
        angle = rng.uniform(0, 2 * math.pi)
    else:
        angle = math.atan2(tangent[1], tangent[0]) + math.pi / 2 + rng.normal(0, math.radians(4))
    return np.array([math.cos(angle), math.sin(angle)])


class Masks:
    """The masks one photo's sampling needs, with the safety margins applied once."""

    def __init__(self, object_mask, part_masks):
        disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * CLEARANCE_PX + 1,) * 2)
        small = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
        as_u8 = object_mask.astype(np.uint8)
        self.object = object_mask
        self.near = cv2.dilate(as_u8, disk).astype(bool)  # object plus clearance
        self.core = cv2.erode(as_u8, disk).astype(bool)  # surely object
        self.part_cores = [cv2.erode(m.astype(np.uint8), small).astype(bool) for m in part_masks]


def sample_positive(rng, part: PartShape, part_index: int, masks: Masks, tries: int = 30):
    """One antipodal grasp across `part`, or None when `tries` candidates all failed."""
    for _ in range(tries):
        point, tangent = point_on_spine(rng, part.spine)
        if part.isotropic:
            point = point + rng.uniform(-3, 3, 2)
        direction = across(rng, part, tangent)
        run = chord(masks.object, point, direction)
        if run is None:
            continue
        back, forward = run
        centre = point + direction * (forward - back) / 2
        opening = back + forward + rng.uniform(*OPENING_MARGIN_PX)
        if opening > MAX_OPENING_PX:
            continue
        grasp = make_grasp(centre, direction, opening, rng.uniform(*part.jaw_px))
        if not inside(masks.part_cores[part_index], centre[None])[0]:
            continue
        if inside(masks.near, jaw_points(grasp)).any() or not in_photo(grasp, masks.object.shape):
            continue
        return grasp
    return None


def clearly_not_graspable(grasp, masks: Masks) -> bool:
    """Centre surely off the object, or a jaw surely on it."""
    centre_off = not inside(masks.near, np.asarray(grasp[:2])[None])[0]
    jaw_on = inside(masks.core, jaw_points(grasp)).any()
    return centre_off or jaw_on


def sample_negative(rng, kind: str, part: PartShape, masks: Masks, tries: int = 30):
    """One rectangle of `kind` ("along", "narrow", "off") that a gripper could not use."""
    if kind not in NEGATIVE_KINDS:
        raise ValueError(f"unknown negative kind {kind!r}; known: {NEGATIVE_KINDS}")
    shape = masks.object.shape
    for _ in range(tries):
        jaw = rng.uniform(10, 25)
        if kind == "off":
            ys, xs = np.nonzero(masks.object)
            centroid = np.array([xs.mean() + 0.5, ys.mean() + 0.5])
            reach = math.hypot(np.ptp(xs), np.ptp(ys)) / 2
            heading = rng.uniform(0, 2 * math.pi)
            centre = centroid + (reach + rng.uniform(10, 45)) * np.array([math.cos(heading), math.sin(heading)])
            direction_angle = rng.uniform(0, 2 * math.pi)
            direction = np.array([math.cos(direction_angle), math.sin(direction_angle)])
            grasp = make_grasp(centre, direction, rng.uniform(20, 60), jaw)
        else:
            point, tangent = point_on_spine(rng, part.spine)
            if kind == "along" and not part.isotropic:
                jitter = rng.normal(0, math.radians(4))
                turn = np.array([[math.cos(jitter), -math.sin(jitter)], [math.sin(jitter), math.cos(jitter)]])
                direction = turn @ tangent
            else:
                direction = across(rng, part, tangent)
            run = chord(masks.object, point, direction)
            if run is None:
                continue
            back, forward = run
            centre = point + direction * (forward - back) / 2
            grasp = make_grasp(centre, direction, (back + forward) * rng.uniform(0.3, 0.7), jaw)
        if in_photo(grasp, shape) and clearly_not_graspable(grasp, masks):
            return grasp
    return None
