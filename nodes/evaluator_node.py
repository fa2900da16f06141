"""evaluator_node: runs and scores closed-loop grasp attempts in the simulated cell.

Each attempt: an object (cycling through ``objects``, asset names) is dropped upright at a random spot and
yaw in the pick area (base frame ``spawn_x``/``spawn_y``) through the simulated controller; after
``settle_s`` the attempt is announced on ``attempt`` (String JSON: attempt, object), which arms robot_node.
With ``pose_source`` = ground_truth the node itself then publishes the true pose on ``object_pose`` (a
perfect estimator: grasping alone is measured); with dope the inference node's estimate drives the robot.
``objects`` is a list or a comma-separated string. The attempt ends when robot_node reports idle or failed on
``robot_status``, after ``timeout_s``, or when the robot has not started ``detect_timeout_s`` after the
announcement. Success: the object lies in the basket. Failure causes: no
detection (no pose arrived), implausible estimate (robot_node refused the pose and sent nothing), robot
error (the status's detail), missed grasp, dropped (held but not in the basket). Pose error: ADD and ADD-S
of the first pose estimate of the attempt against the truth.
After ``attempts`` it writes ``report`` /report.json and strip.png (per attempt: the camera's overlay
image and the outcome) and asks the launch to end. Scoring: ``robot_bridge.attempts``.

Every state change happens in the 0.1 s timer's tick: idle -> settling (object spawned) -> running
(announced) -> resting (ended; the object comes to rest for ``REST_S``) -> scored, removed -> idle. After a
robot error the simulated cell's operator sends the arm home and clears the protective stop.
"""

from __future__ import annotations

import json
import time

import numpy as np
from scipy.spatial.transform import Rotation

from nodes.conversions import IDENTITY, image_to_numpy, matrix_to_pose_msg, pose_msg_to_matrix
from nodes.ros import Node, declare, finish, latched, msgs, run_node
from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.errors import PegasusError
from robot_bridge.attempts import Attempt, score_attempt, strip_image, summarise, write_attempts_report
from robot_bridge.cell import SIM_CELL
from robot_bridge.sim.client import SimCell, body_name

REST_S = 0.3  # after the attempt's end, before asking whether the object is in the basket
SPAWN_CLEARANCE_M = 0.003  # the spawned object's lowest point above the floor


PARAMETERS = (
    ("host", "127.0.0.1"), ("library", ""), ("objects", "noodle_cup_red"), ("attempts", 20), ("seed", 0),
    ("spawn_x", list(SIM_CELL.spawn_x)), ("spawn_y", list(SIM_CELL.spawn_y)), ("settle_s", 1.0), ("timeout_s", 60.0),
    ("detect_timeout_s", 10.0),
    ("hand_eye", IDENTITY), ("pose_source", "dope"), ("report", "out/sim_grasp"))


class EvaluatorNode(Node):
    def __init__(self, **kwargs):
        super().__init__("evaluator_node", **kwargs)
        p = declare(self, PARAMETERS)
        p["objects"] = [o.strip() for o in p["objects"].split(",") if o.strip()]
        if p["pose_source"] not in ("dope", "ground_truth"):
            raise PegasusError(f"evaluator_node: pose_source must be dope or ground_truth, got {p['pose_source']!r}")
        self.params = p
        self.library = AssetLibrary(p["library"] or None)
        self.assets = [self.library.get(name) for name in p["objects"]]
        self.T_base_cam = np.array(p["hand_eye"], dtype=np.float64).reshape(4, 4)
        self.cell = SimCell(p["host"])
        self.rng = np.random.default_rng(int(p["seed"]))
        self.attempt_pub = self.create_publisher(msgs.String, "attempt", latched())
        self.truth_pub = self.create_publisher(msgs.PoseStamped, "object_pose", 1)
        self.create_subscription(msgs.String, "robot_status", self.on_status, 10)
        self.create_subscription(msgs.PoseStamped, "object_pose", self.on_pose, 5)
        self.create_subscription(msgs.Image, "overlay", self.on_overlay, 2)
        self.create_subscription(msgs.Image, "image", self.on_image, 2)
        self.create_subscription(msgs.CameraInfo, "camera_info", self.on_info, 2)
        self.K = None
        self.records, self.strips = [], []
        self.state, self.deadline = "idle", 0.0  # deadline: monotonic s when settling/resting ends
        self.current: Attempt | None = None
        self.running_since_ns = 0  # node-clock ns when the current attempt was announced
        self.pending_status = self.end_status = None  # robot_status that ended the attempt (None: timed out)
        self.create_timer(0.1, self.tick)

    # -- attempt lifecycle (tick) ----------------------------------------------------------------------
    def spawn(self) -> None:
        p, index = self.params, len(self.records)
        asset = self.assets[index % len(self.assets)]
        x, y = self.rng.uniform(*p["spawn_x"]), self.rng.uniform(*p["spawn_y"])
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("z", self.rng.uniform(0, 2 * np.pi)).as_matrix()
        lo, hi = asset.mesh.bounds
        T[:3, 3] = x, y, -lo[2] + SPAWN_CLEARANCE_M
        body = body_name(asset.name, index)
        self.cell.add(body, asset.urdf_path, T)
        self.current = Attempt(index, asset.name, body, np.asarray(asset.mesh.vertices), lo, hi - lo)
        self.pending_status = None
        self.state, self.deadline = "settling", time.monotonic() + float(p["settle_s"])

    def announce(self) -> None:
        c = self.current
        c.T_cam_obj = np.linalg.inv(self.T_base_cam) @ self.cell.pose(c.body)
        c.announced = time.monotonic()
        self.running_since_ns = self.get_clock().now().nanoseconds
        self.state = "running"
        self.attempt_pub.publish(msgs.String(data=json.dumps({"attempt": c.index, "object": c.object})))

    def end(self, status: dict | None) -> None:
        """The attempt is over (``status`` None: timed out); it is scored once the object has come to rest."""
        self.end_status = status
        self.state, self.deadline = "resting", time.monotonic() + REST_S

    def finish(self) -> None:
        c, status = self.current, self.end_status
        in_basket = self.cell.in_basket(c.body)
        record = score_attempt(c, in_basket, status, time.monotonic() - c.announced)
        self.records.append(record)
        self.strips.append(strip_image(c, record, self.K))
        self.cell.remove(c.body)
        if status is not None and status["state"] == "failed":  # the cell's operator: arm home, stop cleared
            self.cell.home()
            self.cell.command("unlock protective stop")
        self.get_logger().info(f"evaluator_node: attempt {c.index + 1}: "
                               f"{'success' if in_basket else 'failure (' + record.cause + ')'}")
        self.state = "idle"

    def timed_out(self) -> bool:
        waited = time.monotonic() - self.current.announced
        return waited > float(self.params["timeout_s"]) or (
            not self.current.robot_started and waited > float(self.params["detect_timeout_s"]))

    def tick(self) -> None:
        p = self.params
        if self.state == "done":
            return
        if self.state == "idle":
            if len(self.records) >= int(p["attempts"]):
                write_attempts_report(p["report"], summarise(self.records, p["pose_source"]), self.strips)
                self.state = "done"
                finish(self)
            else:
                self.spawn()
        elif self.state == "settling" and time.monotonic() >= self.deadline:
            self.announce()
        elif self.state == "running" and self.pending_status is not None:
            status, self.pending_status = self.pending_status, None
            self.end(status)
        elif self.state == "running" and self.timed_out():
            self.end(None)
        elif self.state == "running" and p["pose_source"] == "ground_truth":
            self.publish_truth()
        elif self.state == "resting" and time.monotonic() >= self.deadline:
            self.finish()

    def publish_truth(self) -> None:
        """The true pose in the camera frame, streamed like an estimator's (pose_source ground_truth)."""
        self.truth_pub.publish(msgs.PoseStamped(header=msgs.Header(frame_id="camera",
                                                                   stamp=self.get_clock().now().to_msg()),
                                                pose=matrix_to_pose_msg(self.current.T_cam_obj)))

    # -- subscriptions -----------------------------------------------------------------------------------
    def this_attempts(self, msg) -> bool:
        """Whether a stamped message is from a camera frame taken while the current attempt runs (inference
        can deliver a frame taken before the object was spawned after the attempt has begun)."""
        stamp = msg.header.stamp
        return self.state == "running" and stamp.sec * 1_000_000_000 + stamp.nanosec >= self.running_since_ns

    def on_pose(self, msg) -> None:
        if self.this_attempts(msg) and self.current.estimate is None:
            self.current.estimate = pose_msg_to_matrix(msg.pose)

    def on_overlay(self, msg) -> None:
        if self.this_attempts(msg) and self.current.overlay is None:
            self.current.overlay = image_to_numpy(msg)

    def on_image(self, msg) -> None:
        if self.this_attempts(msg) and self.current.image is None:
            self.current.image = image_to_numpy(msg)

    def on_info(self, msg) -> None:
        self.K = np.array(msg.k, dtype=np.float64).reshape(3, 3)

    def on_status(self, msg) -> None:
        status = json.loads(msg.data)
        if status["state"] in ("planning", "moving") and self.current is not None:
            self.current.robot_started = True
        if status["state"] in ("idle", "failed") and self.current is not None \
                and status.get("attempt") == self.current.index:
            self.pending_status = status  # handled by tick, where every state change happens


NODE_CLASS = EvaluatorNode


def main(args=None) -> None:
    """Console entry point (``ros2 run`` style)."""
    run_node(NODE_CLASS, args)
