"""What a scan did (:class:`ScanReport`, written as ``scan_report.json``): the options, SfM quality, the
metric scale and alignment, the cameras in the scan frame, splat training figures and step timings."""

from __future__ import annotations

import contextlib
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np


@dataclass
class ScanTimings:
    """Seconds spent in the steps of a scan."""

    markers: float = 0.0  # ArUco detection
    sfm: float = 0.0  # structure from motion
    training: float = 0.0  # splat training with its outputs (splats_aligned.ply, previews)
    total: float = 0.0  # the whole scan, asset included

    @contextlib.contextmanager
    def timed(self, step: str):
        """Records the seconds the ``with`` block takes as ``step``."""
        start = time.perf_counter()
        yield
        setattr(self, step, time.perf_counter() - start)


@dataclass(kw_only=True)
class ScanReport:
    """What ``run_scan`` did, section by section; :meth:`to_json` is scan_report.json."""

    options: dict  # the ScanOptions
    images: int  # photos in the folder
    timings_s: ScanTimings
    marker_detections: dict | None = None  # photos_with_markers, markers (ids seen); None with a given scale
    sfm: dict  # SfmResult.report(): images, registered, registered_fraction, points, mean_reprojection_error_px...
    scale: dict  # scale_m_per_unit, source ("aruco" or "--scale"); from markers: their edges' spread
    alignment: dict  # align_to_support_plane's report and S_frame_reconstruction [4, 4]
    cameras_T_cam_frame: dict  # photo name ("second/NAME": the turned-over half) -> T_cam_frame [4, 4] (lists)
    second_half: dict | None = None  # register_second_half's report; None for a one-part scan
    training: dict  # train_splats' report without the loss history: psnr_test, n_splats_final, seconds...
    asset: str  # the asset's folder

    def to_json(self) -> dict:
        """The report as a JSON document (the sections this scan had)."""
        return {key: value for key, value in asdict(self).items() if value is not None}

    def write(self, path: Path) -> Path:
        """Write :meth:`to_json` to ``path`` (scan_report.json); returns the path."""
        path.write_text(json.dumps(self.to_json(), indent=1, default=_json_default))
        return path


def _json_default(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return str(value)
