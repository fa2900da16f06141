"""Line charts drawn with OpenCV (no plotting library needed): loss curves, accuracy-threshold curves."""

from __future__ import annotations

import cv2
import numpy as np

COLOURS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75)]


def _ticks(lo: float, hi: float, log: bool) -> list[float]:
    if log:  # lo, hi: log10 of the range; powers of ten, or 1-2-5 steps within fewer than two decades
        for mantissas in ((1,), (1, 2, 5), (1, 1.5, 2, 3, 4, 5, 6, 7, 8, 9)):
            ticks = [m * 10.0 ** e for e in range(int(np.floor(lo)), int(np.ceil(hi)) + 1) for m in mantissas
                     if lo <= np.log10(m * 10.0 ** e) <= hi]
            if len(ticks) >= 3:
                break
        return ticks
    top = 10 ** np.floor(np.log10(max(hi - lo, 1e-12)))
    step = next(s for s in (top * m for m in (5, 2, 1, 0.5, 0.2, 0.1)) if (hi - lo) / s >= 4)
    return list(np.arange(np.ceil(lo / step) * step, hi + step * 1e-9, step))


def line_chart(series: dict[str, tuple[np.ndarray, np.ndarray]], title: str, xlabel: str, ylabel: str,
               log_y: bool = False, y_range: tuple[float, float] | None = None, size=(800, 480)) -> np.ndarray:
    """An RGB image [H, W, 3] uint8 of the ``series`` {label: (x [N], y [N])} as lines on shared axes, with
    ticks, a legend and the title; ``log_y`` plots y on a log10 axis (non-positive values dropped)."""
    width, height = size
    left, right, top, bottom = 80, 20, 40, 50
    image = np.full((height, width, 3), 255, np.uint8)
    data = {}
    for label, (x, y) in series.items():
        x, y = np.asarray(x, float), np.asarray(y, float)
        keep = np.isfinite(x) & np.isfinite(y) & ((y > 0) if log_y else True)
        if keep.any():
            data[label] = (x[keep], np.log10(y[keep]) if log_y else y[keep])
    cv2.putText(image, title, (left, 26), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    if not data:
        return image
    xs = np.concatenate([d[0] for d in data.values()])
    ys = np.concatenate([d[1] for d in data.values()])
    x0, x1 = xs.min(), max(xs.max(), xs.min() + 1e-9)
    if y_range is not None:
        y0, y1 = (np.log10(v) for v in y_range) if log_y else y_range
    else:
        y0, y1 = ys.min(), max(ys.max(), ys.min() + 1e-9)
        pad = 0.05 * (y1 - y0)
        y0, y1 = y0 - pad, y1 + pad

    def to_px(x, y):
        return np.stack([left + (x - x0) / (x1 - x0) * (width - left - right),
                         height - bottom - (y - y0) / (y1 - y0) * (height - top - bottom)], -1)

    font, grey = cv2.FONT_HERSHEY_SIMPLEX, (200, 200, 200)
    for ty in _ticks(y0, y1, log_y):
        (px, py), = to_px(np.array([x0]), np.array([np.log10(ty) if log_y else ty]))
        cv2.line(image, (left, int(py)), (width - right, int(py)), grey, 1)
        cv2.putText(image, f"{ty:.3g}", (5, int(py) + 4), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    for tx in _ticks(x0, x1, False):
        (px, _), = to_px(np.array([tx]), np.array([y0]))
        cv2.line(image, (int(px), top), (int(px), height - bottom), grey, 1)
        cv2.putText(image, f"{tx:.4g}", (int(px) - 12, height - bottom + 16), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.rectangle(image, (left, top), (width - right, height - bottom), (0, 0, 0), 1)
    cv2.putText(image, xlabel, (width // 2 - 40, height - 12), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(image, ylabel + (" (log)" if log_y else ""), (5, top - 8), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    for n, (label, (x, y)) in enumerate(data.items()):
        colour = COLOURS[n % len(COLOURS)]
        points = np.round(to_px(x, y)).astype(np.int32)
        if len(points) == 1:
            cv2.circle(image, tuple(points[0]), 3, colour, -1)
        cv2.polylines(image, [points], False, colour, 2, cv2.LINE_AA)
        ly = top + 18 + 18 * n
        cv2.line(image, (width - right - 170, ly - 4), (width - right - 145, ly - 4), colour, 3)
        cv2.putText(image, label, (width - right - 140, ly), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return image
