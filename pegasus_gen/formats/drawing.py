"""An object instance drawn on an image: its model's bounding box and axes at a pose, mask contours, a label
(`pegasus view`, inference overlays, evaluation galleries, grasp-attempt strips)."""

from __future__ import annotations

import cv2
import numpy as np

from pegasus_gen.geometry.cuboid import cuboid_points, project_points

# edges of the DOPE-ordered cuboid: top face, bottom face, verticals
BOX_EDGES = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]


def colour_of(obj_id: int) -> tuple[int, int, int]:
    """A stable, saturated RGB colour per object id."""
    hue = (obj_id * 47) % 180
    hsv = np.uint8([[[hue, 220, 255]]])
    return tuple(int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0])


def draw_instance(image: np.ndarray, K: np.ndarray, T_cam_obj: np.ndarray, bbox_min: np.ndarray,
                  bbox_size: np.ndarray, mask: np.ndarray | None, mask_visib: np.ndarray | None,
                  colour: tuple[int, int, int], label: str) -> None:
    """Draw on ``image`` [H, W, 3] uint8 RGB (in place): the full mask's contour (thin), the visible mask's
    (thick), the model's bounding box and axes (x red, y green, z blue) at T_cam_obj [4, 4] (m), a label."""
    for m, thickness in ((mask, 1), (mask_visib, 2)):
        if m is not None and m.any():
            contours, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            cv2.drawContours(image, contours, -1, colour, thickness, cv2.LINE_AA)
    corners = cuboid_points(bbox_min, bbox_size)
    in_front = (corners @ T_cam_obj[:3, :3].T + T_cam_obj[:3, 3])[:, 2] > 1e-3
    if not in_front.all():
        return
    uv = np.round(project_points(corners, T_cam_obj, K) * 16).astype(np.int32)
    for a, b in BOX_EDGES:
        cv2.line(image, tuple(uv[a]), tuple(uv[b]), colour, 1, cv2.LINE_AA, shift=4)
    length = 0.5 * float(np.min(bbox_size))
    axes = np.array([[0, 0, 0], [length, 0, 0], [0, length, 0], [0, 0, length]]) + corners[8]
    axes_uv = np.round(project_points(axes, T_cam_obj, K) * 16).astype(np.int32)
    for k, c in enumerate(((255, 40, 40), (40, 220, 40), (60, 90, 255))):
        cv2.line(image, tuple(axes_uv[0]), tuple(axes_uv[k + 1]), c, 2, cv2.LINE_AA, shift=4)
    x, y = (uv[8] >> 4).tolist()
    cv2.putText(image, label, (x + 4, y - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(image, label, (x + 4, y - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, colour, 1, cv2.LINE_AA)
