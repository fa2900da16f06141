"""Driving a UR5 through ur-rtde, safely: every command is checked against the safety envelope before
anything is sent; moves are sent asynchronously and watched by this side (progress, protective stop,
the state stream going stale) so a lost connection or a stopped robot gives a clean error within
``stale_after`` seconds instead of a hang, with a stop sent where the robot is still reachable.

The gripper is a configurable standard digital output (closed = ``close_value``); its opening, when a
gripper reports it as a voltage, comes from a standard analog input (``width_input``, metres per volt).
``dry_run`` only logs what would be sent (the state is still read, the checks still made).
"""

from __future__ import annotations

import ctypes
import logging
import time
from dataclasses import dataclass, field

import numpy as np

from pegasus_gen.errors import PegasusError
from robot_bridge.kinematics import matrix_to_rtde_pose, rtde_pose_to_matrix
from robot_bridge.safety import SafetyEnvelope

log = logging.getLogger(__name__)


class RobotError(PegasusError):
    """The robot did not do what was asked (protective stop, failed move, timeout); it was left stopped."""


class RobotConnectionError(RobotError):
    """The connection to the controller is gone."""


@dataclass
class GripperConfig:
    output: int = 0  # standard digital output driving the gripper
    close_value: bool = True
    settle_s: float = 0.6  # s the jaws take to close or open
    width_input: int | None = 0  # standard analog input reporting the opening, None: not reported
    width_per_volt: float = 0.01  # m per V


@dataclass
class BridgeConfig:
    host: str = "127.0.0.1"
    speed: float = 0.25  # m/s, moveL
    acceleration: float = 1.2  # m/s^2
    joint_speed: float = 1.05  # rad/s, moveJ
    joint_acceleration: float = 1.4  # rad/s^2
    stop_deceleration: float = 2.0  # m/s^2 (stopL), rad/s^2 (stopJ)
    move_timeout_s: float = 60.0
    stale_after: float = 1.0  # s without a new state from the controller: connection lost
    position_tolerance: float = 0.002  # m between the target and where the TCP ends
    envelope: SafetyEnvelope = field(default_factory=SafetyEnvelope)
    gripper: GripperConfig = field(default_factory=GripperConfig)
    dry_run: bool = False


class UR5:
    """A UR5 over ur-rtde (RTDEControlInterface, RTDEReceiveInterface, RTDEIOInterface)."""

    def __init__(self, config: BridgeConfig | None = None):
        self.config = config or BridgeConfig()
        self.control = self.receive = self.io = None

    # -- connection ------------------------------------------------------------------------------------
    def connect(self) -> "UR5":
        import rtde_control
        import rtde_io
        import rtde_receive

        host = self.config.host
        try:
            self.receive = rtde_receive.RTDEReceiveInterface(host)
            if not self.config.dry_run:
                self.control = rtde_control.RTDEControlInterface(host)
                self.io = rtde_io.RTDEIOInterface(host)
        except RuntimeError as exc:
            self.disconnect()
            raise RobotConnectionError(f"cannot connect to the UR controller at {host}: {exc}") from exc
        log.info("connected to the UR controller at %s%s", host, " (dry run: nothing will be sent)"
                 if self.config.dry_run else "")
        return self

    def disconnect(self) -> None:
        for interface in (self.control, self.io, self.receive):
            if interface is not None:
                try:
                    interface.disconnect()
                except RuntimeError:
                    # ur-rtde 1.6.5: an interface whose controller has gone throws here, and again from its
                    # C++ destructor, which ends the process (std::terminate). It is kept alive for good.
                    ctypes.pythonapi.Py_IncRef(ctypes.py_object(interface))
        self.control = self.receive = self.io = None

    def __enter__(self):
        return self.connect()

    def __exit__(self, *exc):
        self.disconnect()

    def _require(self) -> None:
        if self.receive is None:
            raise RobotConnectionError("not connected (call connect() first)")
        if not self.receive.isConnected():
            raise RobotConnectionError(f"the connection to {self.config.host} is lost")

    # -- state -----------------------------------------------------------------------------------------
    def tcp_pose(self) -> np.ndarray:
        """T_base_tcp [4, 4] as the controller reports it."""
        self._require()
        return rtde_pose_to_matrix(self.receive.getActualTCPPose())

    def joint_positions(self) -> np.ndarray:
        self._require()
        return np.array(self.receive.getActualQ())

    def protective_stopped(self) -> bool:
        self._require()
        return bool(self.receive.isProtectiveStopped())

    def gripper_width(self) -> float | None:
        """The jaws' opening in metres when the gripper reports it on an analog input, else None."""
        g = self.config.gripper
        if g.width_input is None:
            return None
        self._require()
        volts = self.receive.getStandardAnalogInput0() if g.width_input == 0 else self.receive.getStandardAnalogInput1()
        return float(volts) * g.width_per_volt

    # -- motion ----------------------------------------------------------------------------------------
    def move_l(self, target, speed: float | None = None, acceleration: float | None = None) -> None:
        """Move the TCP in a straight line to ``target`` ([4, 4] or [x, y, z, rx, ry, rz], base frame) and
        wait until it is there; checked against the envelope first."""
        c = self.config
        speed = c.speed if speed is None else speed
        acceleration = c.acceleration if acceleration is None else acceleration
        T_target = c.envelope.check_linear(self.tcp_pose(), target, speed, acceleration)
        pose = matrix_to_rtde_pose(T_target).tolist()  # the pose checked (check_linear's is built from it)
        if self._dry(f"moveL {np.round(pose, 4).tolist()} v={speed} a={acceleration}"):
            return
        self._run_async("moveL", lambda: self.control.moveL(pose, speed, acceleration, True),
                        lambda: self.control.stopL(c.stop_deceleration))
        error = np.linalg.norm(self.tcp_pose()[:3, 3] - T_target[:3, 3])
        if error > c.position_tolerance:
            raise RobotError(f"moveL ended {error * 1000:.1f} mm from its target")

    def move_j(self, q, speed: float | None = None, acceleration: float | None = None) -> None:
        """Move to joints ``q`` [6] (rad) and wait; the whole joint path is checked against the envelope."""
        c = self.config
        speed = c.joint_speed if speed is None else speed
        acceleration = c.joint_acceleration if acceleration is None else acceleration
        q = np.asarray(q, float)
        c.envelope.check_joint(self.joint_positions(), q, speed, acceleration, tcp=self._tcp_offset())
        if self._dry(f"moveJ {np.round(q, 4).tolist()} v={speed} a={acceleration}"):
            return
        self._run_async("moveJ", lambda: self.control.moveJ(q.tolist(), speed, acceleration, True),
                        lambda: self.control.stopJ(c.stop_deceleration))

    def _tcp_offset(self) -> np.ndarray:
        """T_flange_tcp [4, 4]: the controller's TCP offset (identity in a dry run, which has no control link)."""
        if self.control is None:
            return np.eye(4)
        try:
            return rtde_pose_to_matrix(self.control.getTCPOffset())
        except RuntimeError as exc:  # ur-rtde: e.g. after a protective stop, when the control script has ended
            raise RobotError(f"the controller did not answer for its TCP offset ({exc}); is the robot in a "
                             "protective stop or its program stopped?") from None

    def stop(self) -> None:
        """Decelerate any motion to a standstill."""
        if self.control is not None and not self.config.dry_run:
            self.control.stopL(self.config.stop_deceleration)

    def _dry(self, what: str) -> bool:
        if self.config.dry_run:
            log.info("dry run, not sent: %s", what)
        return self.config.dry_run

    def _run_async(self, name: str, start, stop) -> None:
        """Send an asynchronous move and watch it to its end (see the module docstring)."""
        c = self.config
        self._require()
        before = self.control.getAsyncOperationProgressEx().operationId()
        if not start():
            self._fail(name, stop, "the controller refused it")
        t0 = time.monotonic()
        last_stamp, last_change = self.receive.getTimestamp(), t0
        while True:
            time.sleep(0.01)
            now = time.monotonic()
            stamp = self.receive.getTimestamp()
            if stamp != last_stamp:
                last_stamp, last_change = stamp, now
            elif now - last_change > c.stale_after:
                raise RobotConnectionError(f"{name}: no state from the controller for {c.stale_after:.1f} s: "
                                           f"connection to {c.host} lost")
            if self.receive.isProtectiveStopped():
                self._fail(name, stop, "protective stop")
            status = self.control.getAsyncOperationProgressEx()
            if status.operationId() != before and not status.isAsyncOperationRunning():
                self._fresh_state()
                return
            if not self.control.isProgramRunning():
                time.sleep(0.1)  # the state streams of control and receive arrive apart: let both catch up
                self._fail(name, stop, "protective stop" if self.receive.isProtectiveStopped()
                           else "the control program on the controller stopped")
            if now - t0 > c.move_timeout_s:
                self._fail(name, stop, f"not finished after {c.move_timeout_s:.0f} s")

    def _fresh_state(self, packets: int = 2, timeout: float = 0.5) -> None:
        """Wait for ``packets`` new states on the receive stream: it arrives apart from the control stream
        that reported the end of a move, and may still show the last instants of it."""
        stamp, seen, t0 = self.receive.getTimestamp(), 0, time.monotonic()
        while seen < packets and time.monotonic() - t0 < timeout:
            time.sleep(0.002)
            now = self.receive.getTimestamp()
            if now != stamp:
                stamp, seen = now, seen + 1

    def _fail(self, name: str, stop, why: str):
        try:
            stop()
        except RuntimeError:
            pass
        raise RobotError(f"{name} failed: {why}; the robot was stopped")

    # -- gripper ---------------------------------------------------------------------------------------
    def gripper(self, close: bool) -> None:
        g = self.config.gripper
        value = g.close_value if close else not g.close_value
        if self._dry(f"digital out {g.output} = {value}"):
            return
        self._require()
        if not self.io.setStandardDigitalOut(g.output, value):
            raise RobotError(f"setting digital output {g.output} failed")
        time.sleep(g.settle_s)

    def gripper_close(self) -> None:
        self.gripper(True)

    def gripper_open(self) -> None:
        self.gripper(False)
