"""The built-in demo library, made by the project's own code: cup-noodle cups and bowls with printed
labels, a snack box, a drink can, and three environments (wooden table, tiled floor, store shelf).

Everything is procedural and deterministic from a seed: textures are drawn with OpenCV (text
included), surfaces are sampled into splats, collision meshes are the exact procedural solids.
``build_demo_library`` writes the assets once and reuses them while their version and seed match.
"""

from __future__ import annotations

import cv2
import numpy as np
import trimesh
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from pegasus_gen.assets.library import AssetLibrary, AssetManifest, DropRegion, save_asset
from pegasus_gen.assets.surface import MAX_EDGE, with_colors
from pegasus_gen.errors import PegasusError
from pegasus_gen.splats.cloud import SplatCloud, concatenate
from pegasus_gen.splats.from_mesh import mesh_to_splats
from pegasus_gen.splats.procedural import plane, wood_texture
from pegasus_gen.splats.surface_splats import surface_splats

DEMO_VERSION = 5
OBJECT_SPACING = 0.0015  # m between splats on objects
ENV_SPACING = 0.002
TABLE_HEIGHT = 0.75  # m, table top above the room floor
SHELF_HEIGHT = 1.1

# name, obj_id, (bottom radius, top radius, height) m, label colours (bg, band, text), brand, flavour
CUPS = [
    ("noodle_cup_red", 1, (0.036, 0.047, 0.105), ((235, 235, 230), (200, 30, 30), (30, 30, 30)),
     "NISSIN", "ORIGINAL"),
    ("noodle_cup_curry", 2, (0.036, 0.047, 0.105), ((250, 200, 40), (120, 60, 20), (60, 30, 10)),
     "NISSIN", "CURRY"),
    ("noodle_cup_seafood", 3, (0.034, 0.045, 0.095), ((40, 90, 200), (240, 240, 240), (250, 250, 250)),
     "OCEAN", "SEAFOOD"),
    ("noodle_cup_chili", 4, (0.030, 0.040, 0.090), ((30, 30, 30), (230, 40, 20), (250, 200, 0)),
     "FIRE", "CHILI"),
    ("noodle_bowl_miso", 5, (0.045, 0.070, 0.065), ((245, 240, 220), (170, 110, 50), (90, 50, 20)),
     "UMAI", "MISO RAMEN"),
    ("noodle_bowl_kimchi", 6, (0.042, 0.065, 0.060), ((200, 30, 50), (250, 250, 250), (255, 255, 255)),
     "SEOUL", "KIMCHI"),
]


def label_texture(bg, band, text_color, brand: str, flavour: str, rng: np.random.Generator,
                  size=(256, 1024)) -> np.ndarray:
    """A wrap-around cup label, rgb uint8 [H, W, 3]: row 0 = top of the cup, columns = angle 0..2pi."""
    h, w = size
    img = np.zeros((h, w, 3), np.uint8)
    img[:] = bg
    img[int(0.72 * h):int(0.86 * h)] = band
    img[int(0.08 * h):int(0.13 * h)] = band
    for k in range(2):  # the label repeats twice around the cup
        x0 = k * w // 2
        cv2.putText(img, brand, (x0 + 40, int(0.42 * h)), cv2.FONT_HERSHEY_DUPLEX, 2.6, text_color, 6, cv2.LINE_AA)
        cv2.putText(img, flavour, (x0 + 48, int(0.62 * h)), cv2.FONT_HERSHEY_SIMPLEX, 1.3, text_color, 3, cv2.LINE_AA)
        cx = x0 + int(0.40 * w)
        cv2.circle(img, (cx, int(0.45 * h)), int(0.12 * h), band, -1, cv2.LINE_AA)
        cv2.putText(img, "3 MIN", (cx - 38, int(0.47 * h)), cv2.FONT_HERSHEY_SIMPLEX, 0.7, bg, 2, cv2.LINE_AA)
    noise = rng.normal(0, 4, img.shape)
    return np.clip(img + noise, 0, 255).astype(np.uint8)


def lid_texture(bg, band, text_color, brand: str, size: int = 512) -> np.ndarray:
    """A round paper lid seen from above, rgb uint8 [size, size, 3] (+x right, +y up)."""
    img = np.zeros((size, size, 3), np.uint8)
    img[:] = band
    cv2.circle(img, (size // 2, size // 2), int(0.42 * size), bg, -1, cv2.LINE_AA)
    scale = 2.0 * size / 512
    (tw, th), _ = cv2.getTextSize(brand, cv2.FONT_HERSHEY_DUPLEX, scale, 4)
    cv2.putText(img, brand, ((size - tw) // 2, (size + th) // 2), cv2.FONT_HERSHEY_DUPLEX, scale, text_color, 4,
                cv2.LINE_AA)
    return img


def _lookup(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Nearest texel colours [N, 3] in [0, 1] at u (columns) and v (rows) in [0, 1]."""
    h, w = image.shape[:2]
    col = np.clip((u * w).astype(int), 0, w - 1)
    row = np.clip((v * h).astype(int), 0, h - 1)
    return image[row, col].astype(np.float64) / 255.0


def frustum_colors(points: np.ndarray, r_top: float, height: float, label: np.ndarray, lid: np.ndarray,
                   bottom_rgb) -> np.ndarray:
    """Colour [N, 3] in [0, 1] of points [N, 3] (m) on a frustum centred on its bounding box: the lid image
    on the top (z = height / 2, the image spanning the top's diameter), ``bottom_rgb`` on the bottom, the
    label around the side (its width once around from +x, its height from top to bottom)."""
    x, y, z = np.asarray(points, dtype=np.float64).T
    colors = _lookup(label, np.mod(np.arctan2(y, x), 2 * np.pi) / (2 * np.pi), (height / 2 - z) / height)
    top, bottom = z >= height / 2 - 1e-9, z <= -height / 2 + 1e-9
    colors[top] = _lookup(lid, 0.5 + x[top] / (2 * r_top), 0.5 - y[top] / (2 * r_top))
    colors[bottom] = np.asarray(bottom_rgb, float)
    return colors


def frustum_splats(r_bottom: float, r_top: float, height: float, colors_of, rng: np.random.Generator,
                   spacing: float = OBJECT_SPACING) -> SplatCloud:
    """A closed truncated cone (cup or bowl), axis z, centred on its bounding box, coloured by ``colors_of``
    (points [N, 3] -> rgb [N, 3], e.g. ``frustum_colors``)."""
    slope = (r_top - r_bottom) / height
    side_area = np.pi * (r_bottom + r_top) * np.hypot(height, r_top - r_bottom)
    n_side = int(side_area / spacing**2)
    z = rng.uniform(-height / 2, height / 2, 4 * n_side)
    r = r_bottom + slope * (z + height / 2)
    z = z[rng.uniform(0, r_top if r_top > r_bottom else r_bottom, len(z)) < r][:n_side]  # density ~ radius
    r = r_bottom + slope * (z + height / 2)
    a = rng.uniform(0, 2 * np.pi, len(z))
    side_n = np.stack([np.cos(a), np.sin(a), np.full(len(z), -slope)], 1)
    parts = [(np.stack([r * np.cos(a), r * np.sin(a), z], 1), side_n / np.linalg.norm(side_n, axis=1, keepdims=True))]
    for sign, radius in ((1.0, r_top), (-1.0, r_bottom)):
        n_cap = int(np.pi * radius**2 / spacing**2)
        rr = radius * np.sqrt(rng.uniform(0, 1, n_cap))
        aa = rng.uniform(0, 2 * np.pi, n_cap)
        pts = np.stack([rr * np.cos(aa), rr * np.sin(aa), np.full(n_cap, sign * height / 2)], 1)
        parts.append((pts, np.tile([0.0, 0.0, sign], (n_cap, 1))))
    pts, normals = (np.concatenate(p) for p in zip(*parts))
    return surface_splats(pts, normals, colors_of(pts), spacing, rng, sh_degree=1, view_dependence=0.03)


def frustum_mesh(r_bottom: float, r_top: float, height: float, sections: int = 48) -> trimesh.Trimesh:
    """The frustum as a closed low-poly solid (the collision mesh)."""
    profile = np.array([[0.0, -height / 2], [r_bottom, -height / 2], [r_top, height / 2], [0.0, height / 2]])
    return trimesh.creation.revolve(profile, sections=sections)


def frustum_surface(r_bottom: float, r_top: float, height: float, colors_of) -> trimesh.Trimesh:
    """The frustum as a closed surface model: vertices at most ``MAX_EDGE`` apart along the profile and around
    the axis, vertex colours from ``colors_of``."""
    corners = np.array([[0.0, -height / 2], [r_bottom, -height / 2], [r_top, height / 2], [0.0, height / 2]])
    steps = [np.linspace(0, 1, int(np.ceil(np.linalg.norm(b - a) / MAX_EDGE)), endpoint=False)
             for a, b in zip(corners[:-1], corners[1:])]
    profile = np.concatenate([a + (b - a) * t[:, None] for a, b, t in zip(corners[:-1], corners[1:], steps)]
                             + [corners[-1:]])
    mesh = trimesh.creation.revolve(profile, sections=int(np.ceil(2 * np.pi * max(r_bottom, r_top) / MAX_EDGE)))
    return with_colors(mesh, colors_of(mesh.vertices))


def box_colors(points: np.ndarray, size, image: np.ndarray, side_rgb) -> np.ndarray:
    """Colour [N, 3] of points [N, 3] (m) on a box of ``size`` centred at the origin: ``image`` spans each
    face normal to y and z (u along the face's first other axis, v down its second), ``side_rgb`` on the
    faces normal to x."""
    points, size = np.asarray(points, dtype=np.float64), np.asarray(size, dtype=np.float64)
    axis = np.argmax(np.abs(points) / size, axis=1)
    colors = np.tile(np.asarray(side_rgb, float), (len(points), 1))
    for a in (1, 2):
        on, (d0, d1) = axis == a, [i for i in range(3) if i != a]
        colors[on] = _lookup(image, points[on, d0] / size[d0] + 0.5, 0.5 - points[on, d1] / size[d1])
    return colors


def snack_box(rng: np.random.Generator):
    """(splats, mesh, surface, name, obj_id): a printed cardboard box."""
    size = (0.16, 0.10, 0.05)
    img = np.full((300, 480, 3), (250, 210, 60), np.uint8)
    cv2.rectangle(img, (0, 200), (480, 300), (200, 40, 40), -1)
    cv2.putText(img, "CRACKERS", (30, 140), cv2.FONT_HERSHEY_DUPLEX, 2.6, (120, 30, 20), 6, cv2.LINE_AA)
    cv2.putText(img, "whole grain", (150, 265), cv2.FONT_HERSHEY_SIMPLEX, 1.2, (255, 255, 255), 3, cv2.LINE_AA)
    side = (0.98, 0.82, 0.24)
    mesh = trimesh.creation.box(size)
    splat_parts = []
    for axis, sign in [(0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1)]:
        dims = [i for i in range(3) if i != axis]
        count = int(size[dims[0]] * size[dims[1]] / OBJECT_SPACING**2)
        pts = rng.uniform(-0.5, 0.5, (count, 3)) * size
        pts[:, axis] = sign * size[axis] / 2
        normal = np.zeros((count, 3))
        normal[:, axis] = sign
        splat_parts.append(surface_splats(pts, normal, box_colors(pts, size, img, side), OBJECT_SPACING, rng,
                                          sh_degree=1, view_dependence=0.02))
    vertices, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, MAX_EDGE, max_iter=20)
    surface = with_colors(trimesh.Trimesh(vertices, faces), box_colors(vertices, size, img, side))
    return concatenate(splat_parts), mesh, surface, "snack_box", 7


def drink_can(rng: np.random.Generator):
    """(splats, mesh, surface, name, obj_id): an aluminium can with a printed label and a metallic sheen."""
    label = label_texture((20, 120, 60), (230, 230, 230), (250, 250, 250), "FIZZ", "LIME SODA", rng)
    lid = np.full((256, 256, 3), 190, np.uint8)
    cv2.circle(lid, (128, 128), 100, (150, 150, 155), 6, cv2.LINE_AA)
    cv2.ellipse(lid, (128, 90), (30, 14), 0, 0, 360, (120, 120, 125), -1, cv2.LINE_AA)
    r, h = 0.033, 0.122

    def colors_of(points):
        return frustum_colors(points, r, h, label, lid, (0.7, 0.7, 0.72))

    splats = frustum_splats(r, r, h, colors_of, rng)
    splats = splats.replace(sh=splats.sh * np.r_[1.0, 3.0, 3.0, 3.0][None, :, None])  # shinier than paper
    return splats, frustum_mesh(r, r, h), frustum_surface(r, r, h, colors_of), "drink_can", 8


def demo_objects(rng: np.random.Generator):
    """Yields (splats, mesh, surface, manifest) for each demo object."""
    for name, obj_id, (rb, rt, h), (bg, band, text), brand, flavour in CUPS:
        label = label_texture(bg, band, text, brand, flavour, rng)
        lid = lid_texture(bg, band, text, brand)

        def colors_of(points, rt=rt, h=h, label=label, lid=lid):
            return frustum_colors(points, rt, h, label, lid, (0.95, 0.95, 0.93))

        splats = frustum_splats(rb, rt, h, colors_of, rng)
        # the printed label breaks the rotational symmetry of the shape: no symmetries declared
        manifest = AssetManifest(name=name, kind="object", obj_id=obj_id, mass=0.08 + 0.4 * h * rt,
                                 geometry={"source": "procedural frustum", "demo_version": DEMO_VERSION})
        yield splats, frustum_mesh(rb, rt, h), frustum_surface(rb, rt, h, colors_of), manifest
    for make in (snack_box, drink_can):
        splats, mesh, surface, name, obj_id = make(rng)
        yield splats, mesh, surface, AssetManifest(
            name=name, kind="object", obj_id=obj_id, mass=0.15 if obj_id == 7 else 0.35,
            geometry={"source": "procedural", "demo_version": DEMO_VERSION})


def _clutter(rng: np.random.Generator, positions) -> tuple[list[SplatCloud], list[trimesh.Trimesh]]:
    """Small props (mugs, blocks) standing at the given (x, y) positions on z = 0."""
    splats, meshes = [], []
    for i, (x, y) in enumerate(positions):
        if i % 2 == 0:
            mesh = trimesh.creation.cylinder(0.04, 0.09, sections=32)
        else:
            mesh = trimesh.creation.box((0.09, 0.06, 0.07))
        mesh.apply_translation([x, y, mesh.bounds[1, 2]])
        colour = np.asarray(rng.uniform(0.2, 0.9, 3) * 255, np.uint8)
        mesh.visual.vertex_colors = np.tile(np.r_[colour, 255], (len(mesh.vertices), 1))
        splats.append(mesh_to_splats(mesh, rng, spacing=ENV_SPACING))
        meshes.append(mesh)
    return splats, meshes


def _quad(size_x: float, size_y: float, T: np.ndarray) -> trimesh.Trimesh:
    """The rectangle |x| <= size_x/2, |y| <= size_y/2 (z = 0, facing +z) moved by T [4, 4]."""
    hx, hy = size_x / 2, size_y / 2
    quad = trimesh.Trimesh([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0]], [[0, 1, 2], [0, 2, 3]])
    return quad.apply_transform(T)


def plaster_texture(u, v):
    """Off-white painted wall with a faint mottling."""
    mottle = 0.03 * np.sin(9.1 * u + 2.0 * np.sin(5.3 * v)) * np.sin(7.7 * v)
    return np.clip(np.array([0.86, 0.85, 0.8]) + mottle[:, None], 0, 1)


def concrete_texture(u, v):
    """Grey floor with broad blotches."""
    blotch = 0.06 * np.sin(3.1 * u + np.sin(2.3 * v)) * np.cos(2.7 * v - 0.5 * u)
    return np.clip(np.array([0.55, 0.54, 0.52]) + blotch[:, None], 0, 1)


ROOM_HALF = 2.0  # m: the room around each demo support is 4 m x 4 m
ROOM_HEIGHT = 2.6
ROOM_SPACING = 0.03  # coarse splats: the room is background


def _room(rng: np.random.Generator, floor_z: float, floor_texture) -> tuple[SplatCloud, trimesh.Trimesh]:
    """Floor and four walls around the support, so that no camera looks into the void (coarse splats)."""
    parts = [(ROOM_HALF * 2, ROOM_HALF * 2, np.eye(4), floor_texture)]
    for k in range(4):  # walls facing inwards
        T = np.eye(4)
        yaw = k * np.pi / 2
        T[:3, :3] = Rotation.from_euler("xz", [-np.pi / 2, yaw]).as_matrix()
        T[:3, 3] = [ROOM_HALF * np.sin(yaw), -ROOM_HALF * np.cos(yaw), ROOM_HEIGHT / 2]
        parts.append((ROOM_HALF * 2, ROOM_HEIGHT, T, plaster_texture))
    splats, meshes = [], []
    lift = np.eye(4)
    lift[2, 3] = floor_z
    for sx, sy, T, texture in parts:
        n = int(sx * sy / ROOM_SPACING**2)
        splats.append(plane(sx, sy, n, texture, rng, sh_degree=0).transformed(lift @ T))
        meshes.append(_quad(sx, sy, lift @ T))
    return concatenate(splats), trimesh.util.concatenate(meshes)


def _table_legs(rng: np.random.Generator, size, height: float) -> tuple[SplatCloud, trimesh.Trimesh]:
    legs = []
    for x in (-1, 1):
        for y in (-1, 1):
            leg = trimesh.creation.box((0.05, 0.05, height))
            leg.apply_translation([x * (size[0] / 2 - 0.06), y * (size[1] / 2 - 0.06), -height / 2 - 0.001])
            leg.visual.vertex_colors = np.tile([110, 75, 45, 255], (len(leg.vertices), 1))
            legs.append(leg)
    mesh = trimesh.util.concatenate(legs)
    return mesh_to_splats(mesh, rng, spacing=0.006), mesh


def _plane_env(name: str, size, texture, rng, clutter_xy, room_floor_z: float, room_floor_texture, extra=()):
    """A textured support rectangle of ``size`` (m) at z = 0 with clutter, ``extra`` (splats, mesh) parts,
    inside a room whose floor is at ``room_floor_z``."""
    sx, sy = size
    floor = plane(sx, sy, int(sx * sy / ENV_SPACING**2), texture, rng, sh_degree=0)
    clutter_splats, clutter_meshes = _clutter(rng, clutter_xy)
    room = _room(rng, room_floor_z, room_floor_texture)
    parts = [room, *extra]
    support = _quad(sx, sy, np.eye(4))
    splats = concatenate([floor, *clutter_splats, *[e[0] for e in parts]]).with_label(0)
    mesh = trimesh.util.concatenate([support, *clutter_meshes, *[e[1] for e in parts]])
    margin = 0.2
    region = DropRegion(x_min=-sx / 2 * (1 - margin), x_max=sx / 2 * (1 - margin),
                        y_min=-sy / 2 * (1 - margin), y_max=sy / 2 * (1 - margin))
    manifest = AssetManifest(name=name, kind="environment", drop_region=region,
                             geometry={"source": "procedural", "demo_version": DEMO_VERSION})
    return splats, mesh, manifest


def tile_texture(u, v):
    """Floor tiles 30 cm with dark grout and a slight per-tile tint."""
    cell = 0.3
    iu, iv = np.floor(u / cell), np.floor(v / cell)
    tint = 0.05 * np.sin(iu * 12.9898 + iv * 78.233)
    base = np.array([0.82, 0.80, 0.76]) + tint[:, None]
    grout = (np.abs(u / cell - np.round(u / cell)) < 0.02) | (np.abs(v / cell - np.round(v / cell)) < 0.02)
    return np.where(grout[:, None], [0.35, 0.33, 0.3], base)


def shelf_texture(u, v):
    """White laminated shelf board with a price rail along the front edge."""
    rgb = np.tile([0.9, 0.9, 0.88], (len(u), 1))
    rgb[v < -0.17] = [0.95, 0.85, 0.2]
    return rgb


def demo_environments(rng: np.random.Generator):
    """Yields (splats, mesh, manifest) for each demo environment (200k-600k splats each)."""
    yield _plane_env("wooden_table", (1.2, 0.8), wood_texture, rng, [(0.45, 0.28), (-0.48, -0.25)],
                     -TABLE_HEIGHT, concrete_texture, extra=[_table_legs(rng, (1.2, 0.8), TABLE_HEIGHT)])
    # the room floor continues the tiles a hair below the support, coarser
    yield _plane_env("tiled_floor", (1.5, 1.0), tile_texture, rng, [(0.6, -0.38), (-0.62, 0.4)], -0.002,
                     tile_texture)
    back = trimesh.creation.box((1.0, 0.02, 0.4))
    back.apply_translation([0, 0.21, 0.2])
    back.visual.vertex_colors = np.tile([235, 235, 230, 255], (len(back.vertices), 1))
    back_splats = mesh_to_splats(back, rng, spacing=ENV_SPACING)
    yield _plane_env("store_shelf", (1.0, 0.4), shelf_texture, rng, [(0.42, 0.1)], -SHELF_HEIGHT, concrete_texture,
                     extra=[(back_splats, back)])


def build_demo_library(library: AssetLibrary, seed: int = 0, force: bool = False) -> list[str]:
    """Write the demo assets into ``library`` (skipping those already built with this version and seed).

    Returns the names of the demo assets.
    """
    rng = np.random.default_rng(seed)
    names = []
    items = [*demo_objects(rng), *((splats, mesh, None, manifest) for splats, mesh, manifest in demo_environments(rng))]
    for splats, mesh, surface, manifest in tqdm(items, desc="demo assets", unit="asset"):
        manifest.geometry["seed"] = seed
        names.append(manifest.name)
        path = library.asset_path(manifest.name)
        if not force and (path / "asset.json").is_file():
            try:
                if library.get(manifest.name).manifest.geometry == manifest.geometry:
                    continue
            except PegasusError:
                pass  # broken: rebuild
        save_asset(path, manifest, splats, mesh, surface, overwrite=True)
    return names
