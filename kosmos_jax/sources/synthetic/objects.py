"""The object catalogue of the synthetic scenes: categories, their parts as polygons, their words.

An object is built in its own frame (pixels at scale 1, centred on the origin, long axis along +x,
y down like the image) and placed into a photo by `place` (position, rotation, scale). Sizes are
those of real objects at about 2 mm per pixel, the scale of Cornell's photos.

Each part carries what the renderer needs (polygon, colour, height profile) and what the grasp
sampler needs: a `spine`, the polyline where a grasp centre may lie, whose local tangent is the
part's long axis (the gripper closes across it); `isotropic` parts (disks) may be grasped from any
direction.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from kosmos_jax import geometry

METRES_PER_PIXEL = 0.002

PALETTE = {
    "red": (200, 32, 38),
    "dark red": (130, 20, 28),
    "orange": (236, 122, 28),
    "yellow": (236, 202, 44),
    "green": (52, 150, 64),
    "dark green": (30, 90, 40),
    "blue": (40, 84, 190),
    "light blue": (120, 170, 225),
    "purple": (120, 60, 152),
    "pink": (232, 122, 164),
    "white": (236, 236, 230),
    "beige": (214, 196, 160),
    "black": (32, 32, 34),
    "grey": (128, 128, 132),
    "silver": (186, 189, 194),
    "brown": (122, 76, 40),
}


@dataclasses.dataclass(frozen=True)
class PartShape:
    """One named part. Polygons are [P, 2] (x, y) arrays in the object's frame (or the photo's)."""

    name: str
    shell: np.ndarray
    colour: tuple[int, int, int]
    base_m: float  # height of the part's outline above the table, metres
    round_profile: bool  # True: cylinder/sphere-like top, False: flat top with a small bevel
    holes: tuple[np.ndarray, ...] = ()
    spine: np.ndarray | None = None  # [S, 2] where grasp centres may lie; None: not graspable
    isotropic: bool = False
    weight: float = 1.0  # share of the photo's positive grasps
    jaw_px: tuple[float, float] = (10.0, 25.0)
    shiny: bool = False


@dataclasses.dataclass(frozen=True)
class Decal:
    """Paint on a part: colour only, or a changed height (a mug's inside) when height_m is set."""

    shell: np.ndarray
    colour: tuple[int, int, int]
    height_m: float | None = None


@dataclasses.dataclass(frozen=True)
class ObjectSpec:
    object_id: int
    category: str  # Cornell z.txt style, e.g. "Remote_Controller"
    name: str
    colours: tuple[str, ...]  # main colour first
    shape_words: tuple[str, ...]
    shape_phrase: str
    purpose: str
    strategy: str
    parts: tuple[PartShape, ...]
    decals: tuple[Decal, ...] = ()


# ---- polygon helpers (object frame) ----------------------------------------------------------


def ellipse(cx, cy, a, b, n=48):
    t = np.linspace(0, 2 * math.pi, n, endpoint=False)
    return np.stack([cx + a * np.cos(t), cy + b * np.sin(t)], axis=-1)


def rect(x0, x1, y0, y1):
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], np.float64)


def stadium(x0, x1, half_w, n_cap=10):
    """A capsule from x0 to x1 (outer extent) along x, of half width half_w."""
    r = min(half_w, (x1 - x0) / 2)
    t = np.linspace(-math.pi / 2, math.pi / 2, n_cap)
    right = np.stack([x1 - r + r * np.cos(t), r * np.sin(t) * half_w / r], -1)
    left = np.stack([x0 + r - r * np.cos(t), -r * np.sin(t) * half_w / r], -1)
    return np.concatenate([right, left])


def band(centre, half_widths):
    """A polygon around a [S, 2] centre line, half_widths[S] to each side of it."""
    tangent = np.gradient(centre, axis=0)
    tangent /= np.linalg.norm(tangent, axis=-1, keepdims=True)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], -1)
    left = centre + normal * half_widths[:, None]
    right = centre - normal * half_widths[:, None]
    return np.concatenate([left, right[::-1]])


def segment(x0, y0, x1, y1, n=8):
    return np.stack([np.linspace(x0, x1, n), np.linspace(y0, y1, n)], -1)


def pick(rng, names):
    return names[int(rng.integers(len(names)))]


def rgb(name):
    return PALETTE[name]


def shade(colour, factor):
    return tuple(int(min(255, max(0, round(c * factor)))) for c in colour)


# ---- the categories ---------------------------------------------------------------------------
# Each builder draws the object's fixed traits (size, colours) from rng and returns the fields of
# ObjectSpec other than object_id.


def build_mug(rng):
    colour = pick(rng, ["red", "blue", "white", "green", "yellow", "black", "orange"])
    radius = rng.uniform(27, 36)
    handle_len = rng.uniform(18, 25)
    handle_hw = rng.uniform(4.0, 5.5)
    body = PartShape("body", ellipse(0, 0, radius, radius), rgb(colour), rng.uniform(0.08, 0.1), False,
                     spine=np.zeros((1, 2)), isotropic=True, weight=1.0)
    handle = PartShape("handle", stadium(radius - 6, radius + handle_len, handle_hw), rgb(colour),
                       0.05, True, spine=segment(radius + 3, 0, radius + handle_len - 3, 0, 6),
                       weight=1.5, jaw_px=(10, 16))
    inside = Decal(ellipse(0, 0, radius - 4, radius - 4), shade(rgb(colour), 0.55), height_m=0.02)
    return dict(category="Mug", name="mug", colours=(colour,), shape_words=("cylindrical", "handled"),
                shape_phrase="cylindrical object with a handle",
                purpose="drinking hot beverages such as coffee or tea",
                strategy="It is cylindrical with a handle on one side. Grasping the handle or across the body "
                "holds it securely. The gripper should close across the handle's narrow width.",
                parts=(body, handle), decals=(inside,))


def build_spoon(rng):
    colour = pick(rng, ["silver", "silver", "white", "black", "red"])
    handle_len = rng.uniform(80, 105)
    handle_hw = rng.uniform(4.0, 5.5)
    head_a, head_b = rng.uniform(18, 23), rng.uniform(11, 15)
    x0 = -(handle_len + 2 * head_a) / 2
    head_cx = x0 + handle_len + head_a - 3
    handle = PartShape("handle", stadium(x0, x0 + handle_len, handle_hw), rgb(colour), 0.012, False,
                       spine=segment(x0 + 10, 0, x0 + handle_len - 12, 0), weight=2.0, shiny=colour == "silver")
    head = PartShape("head", ellipse(head_cx, 0, head_a, head_b), rgb(colour), 0.015, True,
                     spine=segment(head_cx - head_a * 0.35, 0, head_cx + head_a * 0.35, 0, 5),
                     shiny=colour == "silver", jaw_px=(10, 18))
    return dict(category="Large_Spoon", name="spoon", colours=(colour,), shape_words=("long", "thin", "oval"),
                shape_phrase="long and thin object with an oval head",
                purpose="stirring and serving food",
                strategy="It has a long thin handle and a wide oval head. Grasping the handle ensures "
                "stability. The gripper should close across the handle, perpendicular to its length.",
                parts=(handle, head))


def build_bottle(rng):
    colour = pick(rng, ["green", "blue", "white", "brown", "light blue"])
    cap_colour = pick(rng, ["white", "red", "black", "blue"])
    body_len, body_hw = rng.uniform(85, 120), rng.uniform(14, 19)
    neck_len, neck_hw = rng.uniform(26, 34), rng.uniform(6, 7.5)
    cap_len = rng.uniform(8, 11)
    x0 = -(body_len + neck_len + cap_len) / 2
    xb, xn = x0 + body_len, x0 + body_len + neck_len
    body = PartShape("body", stadium(x0, xb, body_hw, 6), rgb(colour), body_hw * METRES_PER_PIXEL, True,
                     spine=segment(x0 + 15, 0, xb - 15, 0), weight=2.0, shiny=True)
    neck = PartShape("neck", rect(xb - 6, xn, -neck_hw, neck_hw), rgb(colour), neck_hw * METRES_PER_PIXEL + 0.01,
                     True, spine=segment(xb + 8, 0, xn - 6, 0, 5), jaw_px=(10, 14), shiny=True)
    cap = PartShape("cap", rect(xn - 1, xn + cap_len, -neck_hw - 1.5, neck_hw + 1.5), rgb(cap_colour),
                    neck_hw * METRES_PER_PIXEL + 0.012, True)
    label_colour = pick(rng, ["white", "yellow", "red", "beige"])
    label = Decal(rect(x0 + body_len * 0.25, x0 + body_len * 0.75, -body_hw, body_hw), rgb(label_colour))
    # the label covers half the body: a colour the object visibly has
    return dict(category="Bottle", name="bottle", colours=tuple(dict.fromkeys((colour, label_colour, cap_colour))),
                shape_words=("cylindrical", "elongated"), shape_phrase="cylindrical object with a narrow neck",
                purpose="holding and pouring liquids",
                strategy="It is cylindrical with a narrow neck and a cap. Grasping the middle of the body "
                "ensures stability. The gripper should be perpendicular to the bottle's length.",
                parts=(body, neck, cap), decals=(label,))


def build_can(rng):
    colour = pick(rng, ["red", "silver", "blue", "green", "yellow"])
    radius = rng.uniform(16, 21)
    body = PartShape("body", ellipse(0, 0, radius, radius), rgb(colour), 0.12, False,
                     spine=np.zeros((1, 2)), isotropic=True, shiny=True)
    top = Decal(ellipse(0, 0, radius - 2.5, radius - 2.5), rgb("silver"))
    tab = Decal(stadium(radius * 0.2, radius * 0.75, 2.5), shade(rgb("silver"), 0.75))
    return dict(category="Aluminum_Can", name="can", colours=(colour, "silver"),
                shape_words=("cylindrical", "round"), shape_phrase="cylindrical object with a round metal top",
                purpose="storing and drinking beverages",
                strategy="It is a standing cylinder, a circle seen from above. Grasping across its diameter "
                "ensures a firm hold. The gripper can close from any direction through the centre.",
                parts=(body,), decals=(top, tab))


def build_box(rng):
    colour = pick(rng, ["red", "orange", "yellow", "blue", "white", "brown"])
    length, half_w = rng.uniform(75, 120), rng.uniform(17, 28)
    body = PartShape("body", rect(-length / 2, length / 2, -half_w, half_w), rgb(colour), rng.uniform(0.04, 0.08),
                     False, spine=segment(-length * 0.3, 0, length * 0.3, 0), jaw_px=(14, 25))
    stripe_colour = pick(rng, ["white", "yellow", "blue", "green"])
    stripe = Decal(rect(-length / 2, length / 2, -half_w * 0.3, half_w * 0.25), rgb(stripe_colour))
    logo = Decal(ellipse(length * 0.2, 0, half_w * 0.5, half_w * 0.5), rgb(pick(rng, ["red", "black", "purple"])))
    return dict(category="Box", name="box", colours=tuple(dict.fromkeys((colour, stripe_colour))), shape_words=("rectangular", "flat"),
                shape_phrase="rectangular and flat object", purpose="storing and packaging food or goods",
                strategy="It is rectangular with flat sides. Grasping across its shorter side ensures "
                "stability. The gripper should be perpendicular to the box's longest side.",
                parts=(body,), decals=(stripe, logo))


def build_apple(rng):
    colour = pick(rng, ["red", "green", "yellow", "dark red"])
    radius = rng.uniform(18, 26)
    t = np.linspace(0, 2 * math.pi, 64, endpoint=False)
    wobble = 1 + 0.04 * np.cos(2 * t + rng.uniform(0, 6.3)) + 0.03 * np.cos(3 * t + rng.uniform(0, 6.3))
    shell = np.stack([radius * wobble * np.cos(t), radius * wobble * np.sin(t)], -1)
    body = PartShape("body", shell, rgb(colour), radius * METRES_PER_PIXEL, True,
                     spine=np.zeros((1, 2)), isotropic=True, shiny=True)
    stem = Decal(stadium(-1.5, 5, 1.3), rgb("brown"))
    return dict(category="Apple", name="apple", colours=(colour,), shape_words=("round", "spherical"),
                shape_phrase="round object with a small stem", purpose="eating as a healthy snack",
                strategy="It is round and fits in the hand. Grasping across its middle ensures stability. "
                "The gripper can approach from any angle through the centre.",
                parts=(body,), decals=(stem,))


def build_marker(rng):
    barrel_colour = pick(rng, ["white", "black", "grey"])
    ink = pick(rng, ["black", "red", "blue", "green"])
    length, half_w = rng.uniform(85, 110), rng.uniform(5.5, 7)
    cap_len = rng.uniform(24, 30)
    x0 = -length / 2
    barrel = PartShape("barrel", stadium(x0, length / 2 - cap_len + 4, half_w, 6), rgb(barrel_colour),
                       half_w * METRES_PER_PIXEL, True, spine=segment(x0 + 10, 0, length / 2 - cap_len - 14, 0),
                       weight=2.0)
    cap = PartShape("cap", stadium(length / 2 - cap_len, length / 2, half_w + 1, 6), rgb(ink),
                    (half_w + 1) * METRES_PER_PIXEL, True,
                    spine=segment(length / 2 - cap_len + 9, 0, length / 2 - 8, 0, 4), jaw_px=(10, 14))
    return dict(category="Marker", name="marker", colours=(barrel_colour, ink),
                shape_words=("cylindrical", "slender"), shape_phrase="slender cylindrical object with a cap",
                purpose="writing and drawing on boards and paper",
                strategy="It is long and slender with a cap at one end. Grasping the barrel near its middle "
                "ensures stability. The gripper should be perpendicular to the marker's length.",
                parts=(barrel, cap))


def build_scissors(rng):
    colour = pick(rng, ["red", "black", "blue", "orange", "green"])
    blade_len = rng.uniform(55, 72)
    base_hw = rng.uniform(6.5, 8)
    ring_a, ring_b, ring_t = rng.uniform(11, 13), rng.uniform(8, 10), rng.uniform(3.5, 4.5)
    x_pivot = -blade_len * 0.25
    blades_shell = np.array([[x_pivot - 4, -base_hw], [x_pivot + blade_len, -1.2],
                             [x_pivot + blade_len, 1.2], [x_pivot - 4, base_hw]])
    blades = PartShape("blades", blades_shell, rgb("silver"), 0.008, False,
                       spine=segment(x_pivot + 12, 0, x_pivot + blade_len * 0.55, 0), shiny=True, jaw_px=(10, 18))
    parts = [blades]
    for side, name in ((-1, "upper handle"), (1, "lower handle")):
        cx, cy = x_pivot - ring_a - 2, side * (ring_b + 1)
        parts.append(PartShape(name, ellipse(cx, cy, ring_a, ring_b, 36), rgb(colour), 0.01, False,
                               holes=(ellipse(cx, cy, ring_a - ring_t, ring_b - ring_t, 36)[::-1],)))
    return dict(category="Scissors", name="scissors", colours=(colour, "silver"),
                shape_words=("sharp", "elongated"),
                shape_phrase="elongated object with two finger loops and pointed blades",
                purpose="cutting paper, cloth and other materials",
                strategy="It has two finger loops and long closed blades. Grasping the closed blades across "
                "their width ensures stability. The gripper should be perpendicular to the blades.",
                parts=tuple(parts))


def build_remote(rng):
    colour = pick(rng, ["black", "grey", "silver", "white"])
    length, half_w = rng.uniform(95, 125), rng.uniform(13, 17)
    body = PartShape("body", stadium(-length / 2, length / 2, half_w, 6), rgb(colour), 0.022, False,
                     spine=segment(-length * 0.32, 0, length * 0.32, 0), jaw_px=(12, 25))
    button_colour = rgb("grey") if colour in ("black", "white") else rgb("black")
    decals = [Decal(ellipse(length * 0.35, 0, 4, 4, 16), rgb("red"))]
    for i in range(6):
        for j in (-1, 0, 1):
            button = ellipse(-length * 0.3 + i * length * 0.08, j * half_w * 0.5, 2.5, 2.0, 12)
            decals.append(Decal(button, button_colour))
    return dict(category="Remote_Controller", name="remote control", colours=(colour,),
                shape_words=("rectangular", "handheld"), shape_phrase="rectangular and handheld object with buttons",
                purpose="controlling electronic devices wirelessly",
                strategy="It is rectangular and has a flat side with buttons. Grasping the middle section "
                "ensures stability. The gripper should be oriented perpendicular to the control's length.",
                parts=(body,), decals=tuple(decals))


def build_plate(rng):
    colour = pick(rng, ["white", "blue", "beige", "green", "yellow"])
    radius = rng.uniform(30, 40)
    body = PartShape("body", ellipse(0, 0, radius, radius, 64), rgb(colour), 0.018, False,
                     spine=np.zeros((1, 2)), isotropic=True, jaw_px=(12, 25))
    well = Decal(ellipse(0, 0, radius * 0.7, radius * 0.7, 48), shade(rgb(colour), 0.9), height_m=0.012)
    return dict(category="Plate", name="plate", colours=(colour,), shape_words=("round", "flat"),
                shape_phrase="round and flat object", purpose="serving and eating food",
                strategy="It is round and flat. Grasping across its diameter ensures stability. The gripper "
                "can close from any direction through the centre.",
                parts=(body,), decals=(well,))


def build_banana(rng):
    colour = pick(rng, ["yellow", "yellow", "green"])
    arc_radius = rng.uniform(70, 105)
    arc_len = rng.uniform(100, 130)
    half_w = rng.uniform(9, 12)
    span = arc_len / arc_radius
    t = np.linspace(-span / 2, span / 2, 40)
    centre = np.stack([arc_radius * np.sin(t), arc_radius * (1 - np.cos(t)) - arc_radius * 0.1], -1)
    s = np.linspace(0, 1, 40)
    widths = half_w * np.clip(np.sin(math.pi * s), 0, None) ** 0.45 + 1.0
    body = PartShape("body", band(centre, widths), rgb(colour), half_w * METRES_PER_PIXEL, True,
                     spine=centre[10:30], weight=1.0, jaw_px=(10, 18))
    tip = centre[-1] + (centre[-1] - centre[-3]) / np.linalg.norm(centre[-1] - centre[-3]) * 5
    stem = PartShape("stem", band(np.stack([centre[-2], tip]), np.array([2.2, 2.2])), rgb("brown"),
                     0.008, False)
    return dict(category="Banana", name="banana", colours=(colour,), shape_words=("curved", "elongated"),
                shape_phrase="curved and elongated object", purpose="eating as a sweet fruit",
                strategy="It is long and curved. Grasping the middle of the curve ensures stability. The "
                "gripper should close across the banana's width, perpendicular to its length.",
                parts=(body, stem))


def build_hammer(rng):
    colour = pick(rng, ["brown", "black", "red", "yellow"])
    handle_len, handle_hw = rng.uniform(95, 120), rng.uniform(5.5, 7)
    head_len, head_hw = rng.uniform(42, 55), rng.uniform(7, 9)
    x0 = -handle_len / 2
    head_x = handle_len / 2 - head_hw
    handle = PartShape("handle", stadium(x0, handle_len / 2 - 2, handle_hw, 6), rgb(colour), 0.015, True,
                       spine=segment(x0 + 12, 0, head_x - head_hw - 20, 0), weight=2.0)
    head = PartShape("head", rect(head_x - head_hw, head_x + head_hw, -head_len / 2, head_len / 2), rgb("grey"),
                     0.02, False, spine=segment(head_x, -head_len / 2 + 5, head_x, head_len / 2 - 5, 9),
                     shiny=True, jaw_px=(8, 14))
    return dict(category="Hammer", name="hammer", colours=(colour, "grey"), shape_words=("long", "T-shaped"),
                shape_phrase="T-shaped object with a long handle and a heavy head",
                purpose="driving nails and striking objects",
                strategy="It has a long handle and a heavy metal head at one end. Grasping the handle away "
                "from the head ensures control. The gripper should be perpendicular to the handle.",
                parts=(handle, head))


def build_screwdriver(rng):
    colour = pick(rng, ["red", "yellow", "blue", "black", "green"])
    handle_len, handle_hw = rng.uniform(42, 55), rng.uniform(8, 10.5)
    shaft_len, shaft_hw = rng.uniform(45, 60), rng.uniform(2.2, 3.0)
    x0 = -(handle_len + shaft_len) / 2
    handle = PartShape("handle", stadium(x0, x0 + handle_len, handle_hw, 8), rgb(colour),
                       handle_hw * METRES_PER_PIXEL, True,
                       spine=segment(x0 + 12, 0, x0 + handle_len - 12, 0, 6), weight=2.0, jaw_px=(10, 20))
    shaft = PartShape("shaft", rect(x0 + handle_len - 2, x0 + handle_len + shaft_len, -shaft_hw, shaft_hw),
                      rgb("silver"), 0.012, True,
                      spine=segment(x0 + handle_len + 12, 0, x0 + handle_len + shaft_len - 8, 0), shiny=True,
                      jaw_px=(10, 16))
    return dict(category="Screwdriver", name="screwdriver", colours=(colour, "silver"),
                shape_words=("long", "cylindrical", "thin"),
                shape_phrase="long object with a thick handle and a thin metal shaft", purpose="turning screws",
                strategy="It has a thick handle and a thin shaft. Grasping the handle ensures stability. The "
                "gripper should be perpendicular to the tool's length.",
                parts=(handle, shaft))


def build_tape(rng):
    colour = pick(rng, ["white", "beige", "brown", "blue", "grey"])
    outer = rng.uniform(24, 32)
    inner = outer - rng.uniform(7, 10)
    mid = (outer + inner) / 2
    ring = PartShape("rim", ellipse(0, 0, outer, outer, 64), rgb(colour), 0.045, False,
                     holes=(ellipse(0, 0, inner, inner, 64)[::-1],), spine=ellipse(0, 0, mid, mid, 32),
                     jaw_px=(8, 14))
    return dict(category="Tape", name="roll of tape", colours=(colour,), shape_words=("round", "ring-shaped"),
                shape_phrase="ring-shaped object with a hole in the middle",
                purpose="sticking and sealing things together",
                strategy="It is a ring with a hole in the middle. Grasping across the rim, one finger inside "
                "the hole, ensures stability. The gripper should close across the rim's thickness.",
                parts=(ring,))


CATEGORIES = {
    "Mug": build_mug,
    "Large_Spoon": build_spoon,
    "Bottle": build_bottle,
    "Aluminum_Can": build_can,
    "Box": build_box,
    "Apple": build_apple,
    "Marker": build_marker,
    "Scissors": build_scissors,
    "Remote_Controller": build_remote,
    "Plate": build_plate,
    "Banana": build_banana,
    "Hammer": build_hammer,
    "Screwdriver": build_screwdriver,
    "Tape": build_tape,
}


def sample_object(rng: np.random.Generator, category: str, object_id: int) -> ObjectSpec:
    """An object of `category` with its fixed traits (size, colours) drawn from rng."""
    if category not in CATEGORIES:
        raise ValueError(f"unknown synthetic category {category!r}; known: {sorted(CATEGORIES)}")
    return ObjectSpec(object_id=object_id, **CATEGORIES[category](rng))


def pose_matrix(x, y, angle, scale):
    """2x3 affine from the object frame to the photo: scale, turn `angle` anticlockwise on screen, move."""
    cos, sin = scale * math.cos(angle), scale * math.sin(angle)
    return np.array([[cos, sin, x], [-sin, cos, y]])


def place(spec: ObjectSpec, matrix: np.ndarray) -> ObjectSpec:
    """The object with every polygon and spine moved into the photo by the 2x3 `matrix`."""

    def move(points):
        return None if points is None else geometry.transform_points(np.asarray(points, np.float64), matrix)

    parts = tuple(dataclasses.replace(p, shell=move(p.shell), holes=tuple(move(h) for h in p.holes),
                                      spine=move(p.spine)) for p in spec.parts)
    decals = tuple(dataclasses.replace(d, shell=move(d.shell)) for d in spec.decals)
    return dataclasses.replace(spec, parts=parts, decals=decals)
