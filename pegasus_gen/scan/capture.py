"""A synthetic scan capture with known truth: a textured cup on a board with ArUco markers, photographed
from a hemisphere of views by a pinhole camera of known intrinsics.

It is what the scan pipeline is tested and benchmarked on (and what `pegasus scan-capture` writes so a
user can try `pegasus scan` without a camera). The truth (intrinsics, every camera pose, marker corners,
the cup's pose) is written next to the images in ``truth.json``; the scan pipeline never reads it.
World frame: the board is the plane z = 0, z up, metres; the cup stands at the origin.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from pegasus_gen.assets import demo_library as demo_assets
from pegasus_gen.errors import PegasusError
from pegasus_gen.geometry.cameras import look_at
from pegasus_gen.io.images import rgb_to_uint8, write_image
from pegasus_gen.render.renderer import check_image_memory, render
from pegasus_gen.scan.markers import aruco_dictionary
from pegasus_gen.splats import procedural as synthetic
from pegasus_gen.splats.cloud import SplatCloud

BOARD_SIZE = 0.50  # m, square
BOARD_SPACING = 0.0012  # m between board splats (an ArUco cell of a 5 cm marker spans ~6 splats)
MARKER_SIZE = 0.05  # m, the black square's edge
MARKER_DICT = "DICT_4X4_50"
MARKER_CENTRES = ((-0.17, -0.17), (0.17, -0.17), (0.17, 0.17), (-0.17, 0.17))  # ids 0..3, metres
TEXELS_PER_M = 2400


def marker_corners_world(centre_xy, size: float) -> np.ndarray:
    """World corners [4, 3] of a marker lying on z = 0, in ArUco order (top-left, top-right,
    bottom-right, bottom-left as printed, "top" towards +y)."""
    cx, cy = centre_xy
    h = size / 2
    return np.array([[cx - h, cy + h, 0], [cx + h, cy + h, 0], [cx + h, cy - h, 0], [cx - h, cy - h, 0]])


def board_texture(rng: np.random.Generator, markers: bool = True) -> np.ndarray:
    """The board's print, rgb uint8 [S, S, 3] covering BOARD_SIZE: multi-scale colour noise with
    scattered shapes (texture for feature matching) and the ArUco markers on white quiet zones."""
    s = int(BOARD_SIZE * TEXELS_PER_M)
    img = np.zeros((s, s, 3), np.float64)
    for cells, weight in ((6, 0.45), (24, 0.35), (96, 0.2)):
        noise = rng.uniform(0, 1, (cells, cells, 3)).astype(np.float32)
        img += weight * cv2.resize(noise, (s, s), interpolation=cv2.INTER_CUBIC)
    img = np.clip(255 * (0.15 + 0.8 * img), 0, 255).astype(np.uint8)
    for _ in range(700):  # blobs and bars with sharp edges: corners for SIFT at every viewing distance
        colour = tuple(int(c) for c in rng.integers(0, 256, 3))
        x, y = (int(v) for v in rng.integers(0, s, 2))
        r = int(rng.integers(4, 30))
        if rng.uniform() < 0.5:
            cv2.circle(img, (x, y), r, colour, -1, cv2.LINE_AA)
        else:
            cv2.rectangle(img, (x, y), (x + r, y + int(rng.integers(3, 20))), colour, -1)
    if not markers:
        return img
    dictionary = aruco_dictionary(MARKER_DICT)
    side = int(MARKER_SIZE * TEXELS_PER_M)
    quiet = side // 4
    for marker_id, (cx, cy) in enumerate(MARKER_CENTRES):
        col = int((cx + BOARD_SIZE / 2) * TEXELS_PER_M)
        row = int((BOARD_SIZE / 2 - cy) * TEXELS_PER_M)  # image rows run towards -y
        x0, y0 = col - side // 2, row - side // 2
        img[y0 - quiet:y0 + side + quiet, x0 - quiet:x0 + side + quiet] = 255
        marker = cv2.aruco.generateImageMarker(dictionary, marker_id, side)
        img[y0:y0 + side, x0:x0 + side] = marker[..., None]
    return img


def board_splats(rng: np.random.Generator, markers: bool = True) -> SplatCloud:
    """The board as flat splats on z = 0 (label 0), with or without its ArUco markers."""
    texture = board_texture(rng, markers)
    n = int((BOARD_SIZE / BOARD_SPACING) ** 2)

    def colours(x, y):
        return demo_assets._lookup(texture, (x + BOARD_SIZE / 2) / BOARD_SIZE, (BOARD_SIZE / 2 - y) / BOARD_SIZE)

    return synthetic.plane(BOARD_SIZE, BOARD_SIZE, n, colours, rng, sh_degree=1, view_dependence=0.01,
                           opacity=0.99)


def cup_splats(rng: np.random.Generator) -> tuple[SplatCloud, float]:
    """The red demo noodle cup in its object frame (bounding-box centre at the origin), label 1;
    returns (splats, height in metres). Its printed label repeats twice around the cup, which would make
    the two sides indistinguishable to feature matching: scattered stickers tell them apart."""
    name, _, (rb, rt, h), (bg, band, text), brand, flavour = demo_assets.CUPS[0]
    label = demo_assets.label_texture(bg, band, text, brand, flavour, rng)
    for _ in range(300):
        colour = tuple(int(c) for c in rng.integers(0, 256, 3))
        x, y = int(rng.integers(0, label.shape[1])), int(rng.integers(0, label.shape[0]))
        cv2.circle(label, (x, y), int(rng.integers(10, 35)), colour, -1, cv2.LINE_AA)
    lid = demo_assets.lid_texture(bg, band, text, brand)

    def colors_of(points):
        return demo_assets.frustum_colors(points, rt, h, label, lid, (0.95, 0.95, 0.93))

    return demo_assets.frustum_splats(rb, rt, h, colors_of, rng).with_label(1), h


def hemisphere_poses(count: int, radius: float, target, rng: np.random.Generator,
                     elevations_deg=(25.0, 60.0)) -> list[np.ndarray]:
    """``count`` T_cam_world [4, 4] on rings of a hemisphere (elevation between the given bounds),
    looking at ``target`` [3] with a little jitter, ordered ring by ring (a walk around the object)."""
    rings = max(1, int(round(np.sqrt(count / 6))))
    per_ring = np.full(rings, count // rings)
    per_ring[: count % rings] += 1
    poses = []
    for ring, n in enumerate(per_ring):
        elevation = np.radians(np.interp(ring, [0, max(rings - 1, 1)], elevations_deg))
        for k in range(n):
            azimuth = 2 * np.pi * (k + 0.5 * ring) / n
            r = radius * rng.uniform(0.9, 1.1)
            eye = np.array([r * np.cos(elevation) * np.cos(azimuth), r * np.cos(elevation) * np.sin(azimuth),
                            r * np.sin(elevation)])
            poses.append(look_at(eye, np.asarray(target) + rng.normal(0, 0.01, 3)))
    return poses


def write_capture(out: str | os.PathLike, views: int = 36, width: int = 480, height: int = 360,
                  seed: int = 0, flipped: bool = False, markers: bool = True, distance: float = 0.55,
                  fov_x_deg: float = 60.0, progress: bool = True) -> Path:
    """Render a capture into ``out``: images/NNNN.png, masks/NNNN.png (the cup's pixels) and truth.json.

    flipped: the cup lies upside down (the second half of a two-part object scan); markers: print the
    ArUco markers on the board; distance: mean camera distance from the cup (m).
    Returns the images folder.
    """
    if views < 1:
        raise PegasusError("a capture needs at least one view")
    if width < 1 or height < 1:
        raise PegasusError(f"a capture needs a positive image size, got {width} x {height}")
    check_image_memory(width, height, labels=1)
    rng = np.random.default_rng(seed)
    board = board_splats(np.random.default_rng(1000), markers)  # the same board in every capture
    cup, cup_height = cup_splats(np.random.default_rng(1001))
    T_world_cup = np.eye(4)
    T_world_cup[2, 3] = cup_height / 2
    if flipped:
        T_world_cup[:3, :3] = np.diag([1.0, -1.0, -1.0])
    cup_world = cup.transformed(T_world_cup)
    fx = width / 2 / np.tan(np.radians(fov_x_deg) / 2)
    K = np.array([[fx, 0, (width - 1) / 2], [0, fx, (height - 1) / 2], [0, 0, 1]])
    poses = hemisphere_poses(views, distance, (0.0, 0.0, cup_height / 3), rng)
    out = Path(out)
    (out / "images").mkdir(parents=True, exist_ok=True)
    (out / "masks").mkdir(parents=True, exist_ok=True)
    truth = {"K": K.tolist(), "width": width, "height": height, "marker_size": MARKER_SIZE if markers else None,
             "marker_dictionary": MARKER_DICT, "T_world_object": T_world_cup.tolist(),
             "markers": {str(i): marker_corners_world(c, MARKER_SIZE).tolist()
                         for i, c in enumerate(MARKER_CENTRES) if markers},
             "images": {}}
    for i, T in enumerate(tqdm(poses, desc="rendering capture", unit="view", disable=not progress)):
        name = f"{i:04d}.png"
        result = render([board, cup_world], K, T, width, height, background=(0.08, 0.08, 0.1), labels=(1,),
                        device="cpu")
        write_image(out / "images" / name, rgb_to_uint8(result.rgb))
        write_image(out / "masks" / name, (255 * result.mask(1)).astype(np.uint8))
        truth["images"][name] = {"T_cam_world": T.tolist()}
    (out / "truth.json").write_text(json.dumps(truth, indent=1))
    return out / "images"
