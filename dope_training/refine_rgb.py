"""Refine a DOPE pose of a rigid object against the RGB image alone: move the model until its silhouette's outline
lies on the edge between the object's colours and its surroundings' (a region-based fit, as in PWP3D and SRT3D).

DOPE reads the object's pose from nine keypoints in a coarse belief map: on real photos its distance is off by
~5 % and its rotation by ~25 degrees (median), far from the 10 % of the diameter that BOP's recall asks. The
outline of a silhouette pins both down: its size gives the distance (1 % of it is a pixel on a 100 px object)
and its shape the rotation, and no depth camera is needed.

Each iteration:

1. renders the model's silhouette (``mesh_silhouette`` on a decimated copy of the mesh) at the current pose in
   a region of interest around it, and takes ``lines`` points evenly along its outer contour with their outward
   normals;
2. learns the colours of the object (inside the silhouette, eroded) and of its surroundings (a band outside it)
   as two RGB histograms, and from them each pixel's probability of being the object;
3. along each contour point's normal (``half_length_px`` each side) finds where the object ends: the offset
   whose split into object inside and background outside explains the line's pixels best (a softmax over the
   offsets' log-likelihoods gives the mean offset and its spread), then, within ``edge_window_px`` of it, where
   the colour changes fastest (sub-pixel: a blurred step's steepest point is the step, whatever the blur, where
   the colour split leans to whichever side the mixed pixels' colours resemble);
4. moves the pose so that the rendered outline passes through these edge points: Gauss-Newton on the six pose
   parameters (a twist in the camera frame) with the rendered silhouette's signed distance at the edge points as
   residuals, its derivatives by finite differences of re-rendered silhouettes, each line weighted by the
   inverse spread of its edge, down-weighted beyond ``huber_px`` while the search is wide and, once it is at
   most ``tukey_from_px``, given no weight beyond ``tukey_px`` (Tukey's biweight: lines where an occluder ends
   the object, which would pull the outline in and the distance out, stop counting once the outline is close).

The search half-length shrinks stage by stage (``half_length_px``). Only the outline is used: a rotation that
leaves the silhouette unchanged (a symmetric object turned about its axis, a face seen edge-on) stays as DOPE
read it. ``support`` (the share of lines whose edge lay within ``support_px`` of the outline in the last
iteration, the one the last, smallest step started from) says how well the image confirms the final pose.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from pegasus_gen.errors import PegasusError
from pegasus_gen.render.silhouette import mesh_silhouette

MAX_FACES = 1500  # ``decimated``'s default: triangles enough for the outline of a 60-200 px object
SUPPORT_SEARCH_PX = 6.0  # ``outline_support`` seeks each edge this far each side of the outline (the fit's last stage)


@dataclass
class RgbRefineParams:
    """The knobs of ``refine_rgb``."""

    lines: int = 120  # contour points (lines along their normals) per iteration
    half_length_px: tuple[float, ...] = (24.0, 24.0, 12.0, 12.0, 6.0, 6.0, 6.0)  # search half-length per iteration
    bins: int = 16  # histogram bins per colour channel
    band_px: int = 16  # width of the band outside the silhouette whose colours are the background's, pixels
    erode_px: int = 2  # pixels eroded from the silhouette before its colours are taken as the object's
    edge_window_px: float = 1.5  # the steepest colour change is sought this far each side of the colour split (0: not)
    huber_px: float = 3.0  # while the search is wide, residuals beyond this many pixels are down-weighted (Huber)
    tukey_from_px: float = 6.0  # from the stage whose search half-length is at most this on, Tukey's biweight:
    tukey_px: float = 4.0  # residuals beyond this many pixels weigh nothing
    step_px: float = 2.0  # finite-difference steps move the outline by about this many pixels
    damping: float = 0.2  # Marquardt damping: each pose parameter's curvature (the normal equations' diagonal) x this
    min_contrast: float = 4.0  # lines whose edge explains them better by fewer nats weigh proportionally less
    support_px: float = 2.0  # a line supports the final pose when its edge lies within this many pixels


@dataclass
class RgbRefinement:
    """T [4, 4] refined T_cam_obj (metres, OpenCV camera frame), support (0..1: share of the contour's lines whose
    edge lay within ``support_px`` of the outline in the last iteration), iterations run."""

    T: np.ndarray
    support: float
    iterations: int


def decimated(vertices: np.ndarray, faces: np.ndarray, max_faces: int = MAX_FACES) -> tuple[np.ndarray, np.ndarray]:
    """The mesh (vertices [V, 3] m, faces [F, 3]) simplified to at most ``max_faces`` triangles (quadric
    decimation, open3d); unchanged when it has no more."""
    if len(faces) <= max_faces:
        return np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(vertices, np.float64)),
                                     o3d.utility.Vector3iVector(np.asarray(faces, np.int32)))
    mesh = mesh.simplify_quadric_decimation(target_number_of_triangles=max_faces)
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.triangles, np.int64)


def read_mesh(path: str | Path, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The triangle mesh at ``path`` (PLY, OBJ, ...) scaled by ``scale`` to metres and ``decimated``: vertices
    [V, 3] m and faces [F, 3]; a PegasusError when it cannot be read or has no faces."""
    import trimesh

    try:
        mesh = trimesh.load(path, process=False, force="mesh")
    except (OSError, ValueError) as exc:
        raise PegasusError(f"{path}: cannot read the mesh ({exc})") from None
    if not len(getattr(mesh, "faces", ())):
        raise PegasusError(f"{path}: not a triangle mesh")
    return decimated(np.asarray(mesh.vertices) * scale, np.asarray(mesh.faces))


def _twist(T: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """T [4, 4] moved by delta [6] (rotation vector about the object's centre in camera axes (rad), translation
    (m), both in the camera frame): R' = exp(w) R, t' = t + v (the centre's rotation does not move it)."""
    out = T.copy()
    out[:3, :3] = Rotation.from_rotvec(delta[:3]).as_matrix() @ T[:3, :3]
    out[:3, 3] = T[:3, 3] + delta[3:]
    return out


class _Roi:
    """A window [x0, y0, w, h] of the image (px) and the camera matrix of its pixels."""

    def __init__(self, uv: np.ndarray, margin: float, width: int, height: int, K: np.ndarray):
        lo = np.floor(uv.min(0) - margin).astype(int)
        hi = np.ceil(uv.max(0) + margin).astype(int)
        self.x0, self.y0 = max(lo[0], 0), max(lo[1], 0)
        self.w, self.h = min(hi[0], width) - self.x0, min(hi[1], height) - self.y0
        self.K = K.copy()
        self.K[0, 2] -= self.x0
        self.K[1, 2] -= self.y0


def _centred(T: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """T [4, 4] of a model whose origin is shifted to ``centre`` [3] (model frame): rotations of the twist then
    turn the object about its centre."""
    out = T.copy()
    out[:3, 3] = T[:3, :3] @ centre + T[:3, 3]
    return out


def _signed_distance(mask: np.ndarray) -> np.ndarray:
    """[H, W] float32 px: distance to the silhouette's outline, positive outside, negative inside."""
    m = mask.astype(np.uint8)
    outside = cv2.distanceTransform(1 - m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    inside = cv2.distanceTransform(m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return outside - inside + np.where(m > 0, 0.5, -0.5).astype(np.float32)


def _sample(image: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Bilinear samples [..., C] of a float32 [H, W] or [H, W, C] image at points [..., 2] (x, y px), borders
    replicated."""
    p = points.reshape(-1, 1, 2).astype(np.float32)
    out = cv2.remap(image, p[..., 0], p[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(points.shape[:-1] + image.shape[2:])


def _contour(mask: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray] | None:
    """``count`` points [N, 2] (px) evenly spaced along the largest outer contour of ``mask`` and their outward
    unit normals [N, 2]; None when the mask is empty or too small."""
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    c = max(contours, key=len).reshape(-1, 2).astype(np.float64)
    if len(c) < 12:
        return None
    idx = np.linspace(0, len(c), count, endpoint=False).astype(int)
    k = max(2, len(c) // 60)  # tangent over a few pixels each side
    tangent = c[(idx + k) % len(c)] - c[(idx - k) % len(c)]
    normal = np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-9)
    points = c[idx]
    probe = np.round(points + 2 * normal).astype(int)  # flip the normals that point into the silhouette
    h, w = mask.shape
    inside = mask[np.clip(probe[:, 1], 0, h - 1), np.clip(probe[:, 0], 0, w - 1)]
    normal[inside] *= -1
    return points, normal


def _foreground_probability(crop: np.ndarray, mask: np.ndarray, params: RgbRefineParams) -> np.ndarray | None:
    """[H, W] float32: each pixel's probability of showing the object, from the colour histograms of the
    silhouette (eroded) and of a band around it; None when either region is empty."""
    m = mask.astype(np.uint8)
    e = params.erode_px
    inner = cv2.erode(m, np.ones((2 * e + 1, 2 * e + 1), np.uint8)) > 0 if e else m > 0
    b = params.band_px
    near = cv2.dilate(m, np.ones((5, 5), np.uint8)) > 0  # the 2 px next to the outline belong to neither
    band = (cv2.dilate(m, np.ones((2 * b + 1, 2 * b + 1), np.uint8)) > 0) & ~near
    if inner.sum() < 10 or band.sum() < 10:
        return None
    q = (crop.astype(np.int32) * params.bins) // 256
    code = (q[..., 0] * params.bins + q[..., 1]) * params.bins + q[..., 2]
    n = params.bins ** 3
    hf = np.bincount(code[inner], minlength=n) + 0.5
    hb = np.bincount(code[band], minlength=n) + 0.5
    pf, pb = hf / hf.sum(), hb / hb.sum()
    return (pf / (pf + pb))[code].astype(np.float32)


def _edges(prob: np.ndarray, points: np.ndarray, normals: np.ndarray,
           half: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Along each line (point [N, 2] + s normal [N, 2], s in -half..half px): the mean offset of the object's
    edge [N] (px, along the outward normal), its spread [N] (px, standard deviation of the softmax over the
    offsets of each split's log-likelihood: object inside, background outside) and its contrast [N] (nats: how
    much better the best split explains the line than the line all object or all background)."""
    s = np.arange(-half, half + 1.0)
    samples = points[:, None, :] + s[None, :, None] * normals[:, None, :]
    p = np.clip(_sample(prob, samples), 1e-3, 1 - 1e-3)
    log_f, log_b = np.log(p), np.log(1 - p)
    # split k: samples [0, k) are the object, [k, L) the background; k = 0..L
    inside = np.concatenate([np.zeros((len(p), 1)), np.cumsum(log_f, axis=1)], axis=1)
    outside = np.concatenate([np.cumsum(log_b[:, ::-1], axis=1)[:, ::-1], np.zeros((len(p), 1))], axis=1)
    ll = inside + outside
    w = np.exp(ll - ll.max(axis=1, keepdims=True))
    w /= w.sum(axis=1, keepdims=True)
    offsets = np.concatenate([s - 0.5, [s[-1] + 0.5]])  # split k lies between samples k-1 and k
    mean = w @ offsets
    spread = np.sqrt(np.maximum(w @ offsets ** 2 - mean ** 2, 0.0))
    contrast = ll.max(axis=1) - np.maximum(ll[:, 0], ll[:, -1])
    return mean, spread, contrast


def _steepest(crop: np.ndarray, points: np.ndarray, normals: np.ndarray, centre: np.ndarray,
              window: float) -> np.ndarray:
    """Along each line (point [N, 2] + s normal [N, 2]), the offset s [N] (px) within ``window`` of ``centre``
    [N] where the colours of ``crop`` [H, W, 3] change fastest (colour difference over 1 px, sampled every 0.25
    px, its peak refined by a parabola)."""
    step = 0.25
    s = centre[:, None] + np.arange(-window - 0.5, window + 0.5 + step / 2, step)[None, :]
    colour = _sample(crop.astype(np.float32), points[:, None, :] + s[..., None] * normals[:, None, :])
    k = round(0.5 / step)
    change = np.linalg.norm(colour[:, 2 * k:] - colour[:, :-2 * k], axis=2)  # at s[:, k:-k]
    i = np.clip(np.argmax(change, axis=1), 1, change.shape[1] - 2)
    rows = np.arange(len(points))
    a, b, c = change[rows, i - 1], change[rows, i], change[rows, i + 1]
    curvature = a - 2 * b + c
    frac = np.where(curvature < 0, 0.5 * (a - c) / np.where(curvature < 0, curvature, -1.0), 0.0)
    return s[rows, i + k] + np.clip(frac, -1.0, 1.0) * step


def _checked(image: np.ndarray, probability: np.ndarray | None) -> np.ndarray:
    """``image`` as an array; a PegasusError when it is not [H, W, 3] uint8 or ``probability`` not [H, W]."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise PegasusError(f"refine_rgb: the image must be [H, W, 3] uint8, not {image.dtype} {image.shape}")
    if probability is not None and np.shape(probability) != image.shape[:2]:
        raise PegasusError(f"refine_rgb: a probability map of {np.shape(probability)} for an image of "
                           f"{image.shape[:2]}")
    return image


def _about_centre(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertices [V, 3] (m) less the centre [3] of their box, and that centre."""
    vertices = np.asarray(vertices, np.float64)
    centre = (vertices.min(0) + vertices.max(0)) / 2
    return vertices - centre, centre


@dataclass
class _Lines:
    """The outline's lines at one pose (steps 1-3 of the module docstring): the region of interest they lie in, the
    edge found along each line [N, 2] (roi px), the rendered outline's signed distance there [N] (px: the residuals),
    each edge's spread [N] (px) and contrast [N] (nats), and the outline's radius (px)."""

    roi: _Roi
    targets: np.ndarray
    residual: np.ndarray
    spread: np.ndarray
    contrast: np.ndarray
    radius_px: float

    def support(self, within_px: float) -> float:
        """The share (0..1) of the lines whose edge lies within ``within_px`` of the outline."""
        return float(np.mean(np.abs(self.residual) <= within_px))


def _lines(image: np.ndarray, K: np.ndarray, T: np.ndarray, local: np.ndarray, faces: np.ndarray, half: float,
           params: RgbRefineParams, probability: np.ndarray | None) -> _Lines | None:
    """The outline's lines of the mesh ``local`` [V, 3] (m, about its centre; ``faces`` [F, 3]) at T [4, 4]
    (``_centred``) in ``image`` [H, W, 3] uint8 (K [3, 3]), each edge searched ``half`` px each side, in the colours
    or in ``probability`` [H, W] (see ``refine_rgb``); None when the object does not project into the image in front
    of the camera, or its outline or colours are too small to read."""
    height, width = image.shape[:2]
    v = local @ T[:3, :3].T + T[:3, 3]
    if (v[:, 2] <= 1e-3).any():
        return None
    uv = v[:, :2] / v[:, 2:3] * K.diagonal()[:2] + K[:2, 2]
    if (uv.max(0) < 0).any() or uv[:, 0].min() >= width or uv[:, 1].min() >= height:
        return None
    roi = _Roi(uv, half + params.band_px + 4, width, height, K)
    if roi.w < 8 or roi.h < 8:
        return None
    crop = image[roi.y0:roi.y0 + roi.h, roi.x0:roi.x0 + roi.w]
    mask = mesh_silhouette(local, faces, roi.K, T, roi.w, roi.h)
    contour = _contour(mask, params.lines)
    if probability is None:
        prob = _foreground_probability(crop, mask, params)
    else:  # its steepest change is sought in it, as in colours (0..255)
        prob = np.asarray(probability[roi.y0:roi.y0 + roi.h, roi.x0:roi.x0 + roi.w], np.float32)
        crop = 255 * prob[..., None]
    if contour is None or prob is None:
        return None
    points, normals = contour
    offset, spread, contrast = _edges(prob, points, normals, half)
    if params.edge_window_px > 0:
        offset = _steepest(crop, points, normals, offset, params.edge_window_px)
    targets = points + offset[:, None] * normals
    radius_px = max(float(np.linalg.norm(uv - uv.mean(0), axis=1).max()), 4.0)
    return _Lines(roi, targets, _sample(_signed_distance(mask), targets), spread, contrast, radius_px)


def refine_rgb(image: np.ndarray, K: np.ndarray, T_cam_obj: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
               params: RgbRefineParams | None = None, probability: np.ndarray | None = None) -> RgbRefinement:
    """The pose T_cam_obj [4, 4] (metres, OpenCV camera frame) of the object whose mesh is ``vertices`` [V, 3]
    (metres, model frame) and ``faces`` [F, 3], fitted to an RGB ``image`` [H, W, 3] uint8 seen with K [3, 3]
    (see the module docstring; pass the mesh through ``decimated`` once per object for speed). With
    ``probability`` [H, W] float32 (0..1: each pixel's probability of showing the object, from elsewhere: the
    outline look, ``dope_training.outline``) the fit takes it instead of the colour histograms' and seeks the
    edge's steepest change in it instead of in the colours. The input pose comes back (support 0) when the object
    does not project into the image in front of the camera."""
    params = params or RgbRefineParams()
    image = _checked(image, probability)
    local, centre = _about_centre(vertices)
    T = _centred(np.asarray(T_cam_obj, np.float64), centre)
    support, done = 0.0, 0
    for half in params.half_length_px:
        lines = _lines(image, K, T, local, faces, half, params, probability)
        if lines is None:
            break
        roi, targets, residual = lines.roi, lines.targets, lines.residual
        # finite differences: steps that move the outline by about step_px
        z = T[2, 3]
        f = K[0, 0]
        steps = params.step_px * np.r_[[1.0 / lines.radius_px] * 3, [z / f] * 2, z / lines.radius_px]
        J = np.empty((len(targets), 6))
        for i in range(6):
            delta = np.zeros(6)
            delta[i] = steps[i]
            moved = mesh_silhouette(local, faces, roi.K, _twist(T, delta), roi.w, roi.h)
            J[:, i] = (_sample(_signed_distance(moved), targets) - residual) / steps[i]
        weight = np.minimum(lines.contrast / params.min_contrast, 1.0) / np.maximum(lines.spread, 0.5) ** 2
        a = np.abs(residual)
        if half <= params.tukey_from_px:
            weight *= np.where(a < params.tukey_px, (1 - (a / params.tukey_px) ** 2) ** 2, 0.0)
        else:
            weight *= np.where(a > params.huber_px, params.huber_px / np.maximum(a, 1e-9), 1.0)
        H = J.T @ (J * weight[:, None])
        g = J.T @ (weight * residual)
        scale = np.diag(H).copy()  # Levenberg-Marquardt on the diagonal: the twist's parts have unlike units
        scale[scale <= 0] = 1.0
        try:
            delta = -np.linalg.solve(H + params.damping * np.diag(scale), g)
        except np.linalg.LinAlgError:
            break
        T = _twist(T, delta)
        support = lines.support(params.support_px)
        done += 1
    return RgbRefinement(_centred(T, -centre), support, done)


def outline_support(image: np.ndarray, K: np.ndarray, T_cam_obj: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                    half_px: float = SUPPORT_SEARCH_PX, params: RgbRefineParams | None = None) -> float:
    """How well ``image`` [H, W, 3] uint8 (K [3, 3]) confirms the pose T_cam_obj [4, 4] (m) of the mesh ``vertices``
    [V, 3] (m, model frame; ``faces`` [F, 3]) as it is: the share (0..1) of its outline's lines whose colour edge,
    searched ``half_px`` each side, lies within ``support_px`` of the outline (``RgbRefinement.support`` without
    moving the pose); 0 when the object does not project into the image in front of the camera."""
    params = params or RgbRefineParams()
    local, centre = _about_centre(vertices)
    lines = _lines(_checked(image, None), K, _centred(np.asarray(T_cam_obj, np.float64), centre), local, faces,
                   half_px, params, None)
    return 0.0 if lines is None else lines.support(params.support_px)
