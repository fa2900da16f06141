"""evaluator_node: runs and scores closed-loop grasp attempts in the simulated cell.

Each attempt: an object (cycling through ``objects``, asset names) is dropped upright at a random spot and
yaw in the pick area (base frame ``spawn_x``/``spawn_y``) through the simulated controller; after
``settle_s`` the attempt is announced on ``attempt`` (String JSON: attempt, object), which arms robot_node.
With ``pose_source`` = ground_truth the node itself then publishes the true pose on ``object_pose`` (a
perfect estimator: grasping alone is measured); with dope the inference node's estimate drives the robot.
``objects`` is a list or a comma-separated string. The attempt ends when robot_node reports idle or failed on
``robot_status``, after ``timeout_s``, or when the robot has not started ``detect_timeout_s`` after the
announcement. Success: the object lies in the basket. Failure causes: no
detection (no pose arrived), robot error (the status's detail), missed grasp, dropped (held but not in
the basket). Pose error: ADD and ADD-S of the first pose estimate of the attempt against the truth.
After ``attempts`` it writes ``report`` /report.json and strip.png (per attempt: the camera's overlay
image and the outcome) and asks the launch to end.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from dope_training.evaluate import add_error, adds_error
from nodes.ros import Node, latched, msgs, run_node
from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.dataset.view import draw_instance
from pegasus_gen.errors import PegasusError
from pegasus_gen.io.images import write_image
from robot_bridge.sim.client import dashboard_command, sim_object_pose


class EvaluatorNode(Node):
    def __init__(self, **kwargs):
        super().__init__("evaluator_node", **kwargs)
        p = {name: self.declare_parameter(name, default).value for name, default in (
            ("host", "127.0.0.1"), ("library", ""), ("objects", ["noodle_cup_red"]), ("attempts", 20), ("seed", 0),
            ("spawn_x", [-0.55, -0.38]), ("spawn_y", [-0.12, 0.12]), ("settle_s", 1.0), ("timeout_s", 60.0),
            ("detect_timeout_s", 10.0),
            ("hand_eye", list(np.eye(4).ravel())), ("pose_source", "dope"), ("report", "out/sim_grasp"))}
        if isinstance(p["objects"], str):
            p["objects"] = [o.strip() for o in p["objects"].split(",") if o.strip()]
        if p["pose_source"] not in ("dope", "ground_truth"):
            raise PegasusError(f"evaluator_node: pose_source must be dope or ground_truth, got {p['pose_source']!r}")
        self.params = p
        self.library = AssetLibrary(p["library"] or None)
        self.assets = [self.library.get(name) for name in p["objects"]]
        self.T_base_cam = np.array(p["hand_eye"], dtype=np.float64).reshape(4, 4)
        self.rng = np.random.default_rng(int(p["seed"]))
        self.attempt_pub = self.create_publisher(msgs.String, "attempt", latched())
        self.truth_pub = self.create_publisher(msgs.PoseStamped, "object_pose", 1)
        self.create_subscription(msgs.String, "robot_status", self.on_status, 10)
        self.create_subscription(msgs.PoseStamped, "object_pose", self.on_pose, 5)
        self.create_subscription(msgs.Image, "overlay", self.on_overlay, 2)
        self.create_subscription(msgs.Image, "image", self.on_image, 2)
        self.create_subscription(msgs.CameraInfo, "camera_info", self.on_info, 2)
        self.K = None
        self.records, self.strips, self.attempt, self.state = [], [], 0, "idle"
        self.current, self.pending_status = None, None
        self.create_timer(0.1, self.tick)

    def command(self, text: str) -> str:
        return dashboard_command(self.params["host"], text)

    # -- attempt lifecycle -----------------------------------------------------------------------------
    def spawn(self) -> None:
        p = self.params
        asset = self.assets[self.attempt % len(self.assets)]
        name = f"{asset.name}#{self.attempt}"
        x, y = self.rng.uniform(*p["spawn_x"]), self.rng.uniform(*p["spawn_y"])
        yaw = self.rng.uniform(0, 2 * np.pi)
        q = Rotation.from_euler("z", yaw).as_quat()
        z = -asset.mesh.bounds[0, 2] + 0.003
        self.command(f"sim add {name} {asset.urdf_path} {x} {y} {z} {q[0]} {q[1]} {q[2]} {q[3]}")
        self.current = {"attempt": self.attempt, "object": asset.name, "name": name, "asset": asset,
                        "spawned": time.monotonic(), "announced": None, "estimate": None, "overlay": None}
        self.state = "settling"

    def announce(self) -> None:
        c = self.current
        c["T_base_obj"] = sim_object_pose(self.params["host"], c["name"])
        c["announced"] = time.monotonic()
        self.state = "running"
        self.attempt_pub.publish(msgs.String(data=json.dumps({"attempt": c["attempt"], "object": c["object"]})))

    def publish_truth(self) -> None:
        """The true pose in the camera frame, streamed like an estimator's (pose_source ground_truth)."""
        T_cam_obj = np.linalg.inv(self.T_base_cam) @ self.current["T_base_obj"]
        self.truth_pub.publish(msgs.PoseStamped(header=msgs.Header(frame_id="camera"),
                                                pose=msgs.matrix_to_pose(T_cam_obj, msgs.Pose)))

    def on_pose(self, msg) -> None:
        if self.state == "running" and self.current["estimate"] is None:
            self.current["estimate"] = msgs.pose_to_matrix(msg.pose)

    def on_overlay(self, msg) -> None:
        if self.state == "running" and self.current["overlay"] is None:
            self.current["overlay"] = msgs.image_to_numpy(msg)

    def on_image(self, msg) -> None:
        if self.state == "running" and self.current.get("image") is None:
            self.current["image"] = msgs.image_to_numpy(msg)

    def on_info(self, msg) -> None:
        self.K = np.array(msg.k, dtype=np.float64).reshape(3, 3)

    def on_status(self, msg) -> None:
        status = json.loads(msg.data)
        if status["state"] in ("planning", "moving") and self.current is not None:
            self.current["robot_started"] = True
        if status["state"] in ("idle", "failed") and self.current is not None \
                and status.get("attempt") == self.current["attempt"]:
            self.pending_status = status  # handled by tick, where every state change happens

    def finish(self, status: dict | None) -> None:
        c = self.current
        time.sleep(0.3)  # let the object come to rest
        in_basket = self.command(f"sim in_basket {c['name']}") == "true"
        if in_basket:
            cause = ""
        elif status is None:
            cause = "no detection" if c["estimate"] is None else (
                "robot timeout" if c.get("robot_started") else "robot did not start")
        elif status["state"] == "failed":
            cause = f"robot error: {status['detail']}"
        elif "nothing between the jaws" in status["detail"]:
            cause = "missed grasp"
        else:
            cause = "dropped"
        record = {"attempt": c["attempt"], "object": c["object"], "success": in_basket, "cause": cause,
                  "seconds": round(time.monotonic() - c["announced"], 2)}
        if c["estimate"] is not None:
            points = np.asarray(c["asset"].mesh.vertices)
            T_cam_true = np.linalg.inv(self.T_base_cam) @ c["T_base_obj"]
            record["add_m"] = add_error(points, c["estimate"], T_cam_true)
            record["adds_m"] = adds_error(points, c["estimate"], T_cam_true)
        self.records.append(record)
        c["record"] = record
        self.strips.append(self._strip(c))
        self.command(f"sim remove {c['name']}")
        if status is not None and status["state"] == "failed":  # the cell's operator: arm home, stop cleared
            self.command("sim home")
            self.command("unlock protective stop")
        self.get_logger().info(f"evaluator_node: attempt {c['attempt'] + 1}: "
                               f"{'success' if in_basket else 'failure (' + cause + ')'}")
        self.attempt += 1
        self.state = "idle"

    def _strip(self, c: dict) -> np.ndarray:
        """The attempt's picture: the estimate's overlay (else the camera image) with the true pose's box
        in green, and the outcome."""
        image = c["overlay"] if c["overlay"] is not None else c.get("image")
        image = np.zeros((480, 640, 3), np.uint8) if image is None else image.copy()
        if self.K is not None:
            lo, hi = c["asset"].mesh.bounds
            draw_instance(image, self.K, np.linalg.inv(self.T_base_cam) @ c["T_base_obj"], lo, hi - lo, None, None,
                          (40, 220, 40), "truth")
        image = cv2.resize(image, (320, int(round(320 * image.shape[0] / image.shape[1]))))
        text = f"#{c['attempt'] + 1} {c['object']}: " + ("OK" if c["record"]["success"] else c["record"]["cause"])
        cv2.putText(image, text[:48], (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(image, text[:48], (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    (40, 220, 40) if c["record"]["success"] else (240, 60, 60), 1, cv2.LINE_AA)
        return image

    def tick(self) -> None:
        p = self.params
        if getattr(self, "shutdown_requested", False):
            return
        if self.state == "idle":
            if self.attempt >= int(p["attempts"]):
                self.write_report()
                self.shutdown_requested = True
                return
            self.spawn()
        elif self.state == "settling" and time.monotonic() - self.current["spawned"] >= float(p["settle_s"]):
            self.announce()
        elif self.state == "running" and self.pending_status is not None:
            status, self.pending_status = self.pending_status, None
            self.finish(status)
        elif self.state == "running" and (
                time.monotonic() - self.current["announced"] > float(p["timeout_s"])
                or (not self.current.get("robot_started")
                    and time.monotonic() - self.current["announced"] > float(p["detect_timeout_s"]))):
            self.finish(None)
        elif self.state == "running" and p["pose_source"] == "ground_truth":
            self.publish_truth()

    def summary(self) -> dict:
        successes = sum(r["success"] for r in self.records)
        causes = {}
        for r in self.records:
            if r["cause"]:
                causes[r["cause"]] = causes.get(r["cause"], 0) + 1
        adds = [r["adds_m"] for r in self.records if "adds_m" in r]
        return {"attempts": len(self.records), "successes": successes,
                "success_rate": successes / max(len(self.records), 1), "failure_causes": causes,
                "median_adds_m": float(np.median(adds)) if adds else None,
                "pose_source": self.params["pose_source"],
                "records": self.records}

    def write_report(self) -> Path:
        out = Path(self.params["report"])
        out.mkdir(parents=True, exist_ok=True)
        (out / "report.json").write_text(json.dumps(self.summary(), indent=1))
        if self.strips:
            rows = [np.concatenate(self.strips[i:i + 5] + [np.zeros_like(self.strips[0])] * (5 - len(self.strips[i:i + 5])),
                                   axis=1) for i in range(0, len(self.strips), 5)]
            write_image(out / "strip.png", np.concatenate(rows, axis=0))
        return out


NODE_CLASS = EvaluatorNode


def main(args=None) -> None:
    """Console entry point (``ros2 run`` style)."""
    run_node(NODE_CLASS, args)
