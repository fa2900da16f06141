"""Scoring closed-loop grasp attempts (evaluator_node): what an attempt saw, why it failed, the report.

An attempt succeeds when the object lies in the basket at its end. Otherwise its cause is one of the
``FailureCause`` values: no detection (the attempt timed out and no pose arrived), robot timeout (a pose
arrived, the robot started but did not finish in time), robot did not start (a pose arrived, the robot did
not move in time), implausible estimate (the robot node refused the pose estimate before sending anything:
``robot_bridge.plausibility``; its reason is in the robot node's status and log, not in the cause, so the
report counts them together), robot error (the robot node failed otherwise; the cause carries its detail),
missed grasp (the gripper closed on nothing), dropped (held, but not in the basket). Pose error: ADD and
ADD-S of the attempt's first pose estimate against the true pose (``pegasus_gen.geometry.pose_error``). The
report (report.json): attempts, successes, success_rate, failure_causes (cause -> count), median_adds_m,
pose_source and records (``AttemptRecord``); strip.png: per attempt a 320 px wide picture (the estimate's
overlay with the true box, the outcome), 5 a row.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

import cv2
import numpy as np

from pegasus_gen.formats.drawing import draw_instance
from pegasus_gen.geometry.pose_error import add_error, adds_error
from pegasus_gen.io.files import write_atomic
from pegasus_gen.io.images import write_image

STRIP_WIDTH = 320  # px, one attempt's picture
STRIP_COLUMNS = 5
BLANK_IMAGE_SHAPE = (480, 640, 3)  # the picture when the attempt saw no image
TRUTH_COLOUR, FAILURE_COLOUR = (40, 220, 40), (240, 60, 60)
MISSED_GRASP_DETAIL = "nothing between the jaws"  # robot_node's detail when the gripper closed on nothing
IMPLAUSIBLE_DETAIL = "implausible estimate: "  # how robot_node's detail starts when it refused the estimate


class FailureCause(str, Enum):
    """Why an attempt failed, as report.json spells it (ROBOT_ERROR is followed by ": " and the detail)."""

    NO_DETECTION = "no detection"
    ROBOT_TIMEOUT = "robot timeout"
    ROBOT_DID_NOT_START = "robot did not start"
    IMPLAUSIBLE = "implausible estimate"
    ROBOT_ERROR = "robot error"
    MISSED_GRASP = "missed grasp"
    DROPPED = "dropped"


@dataclass
class Attempt:
    """One attempt in progress: the spawned object and the first of each thing the attempt saw.

    ``index``: 0-based; ``object``: the asset's name; ``body``: the simulated object's name; ``points``
    [N, 3] m: the object model's vertices (pose errors); ``bbox_min``/``bbox_size`` [3] m: its model box;
    ``T_cam_obj`` [4, 4] m: the true pose in the camera frame, known once the object has settled;
    ``estimate`` [4, 4] m: the first pose estimate (camera frame); ``overlay``/``image`` [H, W, 3] uint8 RGB:
    the first estimator overlay and camera image (each from a frame taken after the announcement);
    ``announced``: monotonic seconds; ``robot_started``: the robot node has reported planning or moving."""

    index: int
    object: str
    body: str
    points: np.ndarray
    bbox_min: np.ndarray
    bbox_size: np.ndarray
    announced: float | None = None
    T_cam_obj: np.ndarray | None = None
    estimate: np.ndarray | None = None
    overlay: np.ndarray | None = None
    image: np.ndarray | None = None
    robot_started: bool = False


@dataclass
class AttemptRecord:
    """One scored attempt: ``attempt`` (0-based), the asset name, success, the cause ("" on success), the
    seconds from the announcement to the end, and ADD/ADD-S (m; None without a pose estimate)."""

    attempt: int
    object: str
    success: bool
    cause: str
    seconds: float
    add_m: float | None = None
    adds_m: float | None = None

    def to_json(self) -> dict:
        """The record as report.json lists it (add_m/adds_m only with a pose estimate)."""
        out = {"attempt": self.attempt, "object": self.object, "success": self.success, "cause": self.cause,
               "seconds": self.seconds}
        if self.adds_m is not None:
            out.update(add_m=self.add_m, adds_m=self.adds_m)
        return out


def failure_cause(in_basket: bool, status: dict | None, estimated: bool, robot_started: bool) -> str:
    """"" when the object is in the basket, else the cause (a ``FailureCause`` value). ``status``: the robot
    node's last robot_status (state idle or failed, detail), None when the attempt timed out."""
    if in_basket:
        return ""
    if status is None:
        if not estimated:
            return FailureCause.NO_DETECTION.value
        return (FailureCause.ROBOT_TIMEOUT if robot_started else FailureCause.ROBOT_DID_NOT_START).value
    if status["state"] == "failed" and status["detail"].startswith(IMPLAUSIBLE_DETAIL):
        return FailureCause.IMPLAUSIBLE.value
    if status["state"] == "failed":
        return f"{FailureCause.ROBOT_ERROR.value}: {status['detail']}"
    if MISSED_GRASP_DETAIL in status["detail"]:
        return FailureCause.MISSED_GRASP.value
    return FailureCause.DROPPED.value


def score_attempt(attempt: Attempt, in_basket: bool, status: dict | None, seconds: float) -> AttemptRecord:
    """The record of a finished ``attempt``: its cause (``failure_cause``), ``seconds`` rounded to 0.01 and,
    with a pose estimate, its ADD and ADD-S (m) against the true pose."""
    record = AttemptRecord(attempt.index, attempt.object, in_basket,
                           failure_cause(in_basket, status, attempt.estimate is not None, attempt.robot_started),
                           round(seconds, 2))
    if attempt.estimate is not None:
        record.add_m = add_error(attempt.points, attempt.estimate, attempt.T_cam_obj)
        record.adds_m = adds_error(attempt.points, attempt.estimate, attempt.T_cam_obj)
    return record


def summarise(records: list[AttemptRecord], pose_source: str) -> dict:
    """The report (report.json): attempts, successes, success_rate, failure_causes (cause -> count, in
    order of first occurrence), median_adds_m (m, None without estimates), pose_source, records."""
    successes = sum(r.success for r in records)
    causes = {}
    for r in records:
        if r.cause:
            causes[r.cause] = causes.get(r.cause, 0) + 1
    adds = [r.adds_m for r in records if r.adds_m is not None]
    return {"attempts": len(records), "successes": successes, "success_rate": successes / max(len(records), 1),
            "failure_causes": causes, "median_adds_m": float(np.median(adds)) if adds else None,
            "pose_source": pose_source, "records": [r.to_json() for r in records]}


def strip_image(attempt: Attempt, record: AttemptRecord, K: np.ndarray | None) -> np.ndarray:
    """[h, STRIP_WIDTH, 3] uint8 RGB: the attempt's overlay (else its camera image, else black) with the true
    pose's model box in green (when the camera K [3, 3] px is known), and the outcome written on top."""
    image = attempt.overlay if attempt.overlay is not None else attempt.image
    image = np.zeros(BLANK_IMAGE_SHAPE, np.uint8) if image is None else image.copy()
    if K is not None:
        draw_instance(image, K, attempt.T_cam_obj, attempt.bbox_min, attempt.bbox_size, None, None, TRUTH_COLOUR,
                      "truth")
    image = cv2.resize(image, (STRIP_WIDTH, int(round(STRIP_WIDTH * image.shape[0] / image.shape[1]))))
    text = f"#{record.attempt + 1} {record.object}: " + ("OK" if record.success else record.cause)
    cv2.putText(image, text[:48], (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(image, text[:48], (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                TRUTH_COLOUR if record.success else FAILURE_COLOUR, 1, cv2.LINE_AA)
    return image


def strip_mosaic(strips: list[np.ndarray]) -> np.ndarray:
    """The ``strip_image`` pictures (same shape [h, w, 3]) in rows of STRIP_COLUMNS, the last row padded
    with black: [rows * h, STRIP_COLUMNS * w, 3]."""
    blank = np.zeros_like(strips[0])
    rows = [strips[i:i + STRIP_COLUMNS] for i in range(0, len(strips), STRIP_COLUMNS)]
    return np.concatenate([np.concatenate(row + [blank] * (STRIP_COLUMNS - len(row)), axis=1) for row in rows],
                          axis=0)


def write_attempts_report(out: str | Path, report: dict, strips: list[np.ndarray]) -> Path:
    """``out``/report.json (``summarise``'s dict) and, with any attempt, ``out``/strip.png; returns ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "report.json", lambda f: f.write(json.dumps(report, indent=1).encode()))
    if strips:
        write_image(out / "strip.png", strip_mosaic(strips))
    return out
