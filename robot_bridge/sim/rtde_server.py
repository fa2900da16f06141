"""The simulated UR controller's RTDE server (port 30004), RTDE v2 (``rtde_protocol``): any output recipe of the
variables the cell has (others as zeros of their type), streamed at the recipe's frequency (at most
``max_frequency``); input recipes of registers, digital outputs and the speed slider. Each connection has its own
recipes and stream; inputs go to one shared table.

Robot state as RTDE variables: robot_mode 7 (RUNNING), safety_mode 1 (NORMAL) or 3 (PROTECTIVE_STOP),
robot_status_bits (power on, program running), safety_status_bits (normal / protective stop), runtime_state
2 (PLAYING) while a program runs and 1 (STOPPED) otherwise, digital outputs; standard digital output
``gripper_output`` closes the gripper, standard analog input 0 reports its opening.
"""

from __future__ import annotations

import socket
import struct
import threading
import time

from robot_bridge.kinematics import matrix_to_rtde_pose
from robot_bridge.sim import rtde_protocol as rp
from robot_bridge.sim.dashboard import CONTROLLER_VERSION

ROBOT_MODE_RUNNING, SAFETY_NORMAL, SAFETY_PROTECTIVE_STOP = 7, 1, 3
RUNTIME_STOPPED, RUNTIME_PLAYING = 1, 2
GRIPPER_METRES_PER_VOLT = 0.01  # the gripper reports its opening on standard analog input 0


class RtdeServer:
    """RTDE connections of ``controller`` (a ``controller.SimController``): ``serve(conn)`` answers one
    connection's requests and streams its output recipes until it closes."""

    def __init__(self, controller):
        self.c = controller

    def values(self, names: list[str], kinds: list[str]) -> list:
        """The current values of the RTDE output variables ``names`` (of types ``kinds``); the state is
        read once per call (one forward kinematics), not once per variable."""
        s, sim = self.c.state, self.c.sim
        tcp_pose = tuple(matrix_to_rtde_pose(sim.tcp_pose()))
        state = {
            "timestamp": self.c.elapsed(), "actual_q": tuple(sim.q), "target_q": tuple(sim.q),
            "actual_qd": tuple(sim.qd), "target_qd": tuple(sim.qd),
            "actual_TCP_pose": tcp_pose, "target_TCP_pose": tcp_pose,
            "tcp_offset": tuple(matrix_to_rtde_pose(sim.tcp)),
            "robot_mode": ROBOT_MODE_RUNNING, "joint_mode": (253,) * 6,
            "safety_mode": SAFETY_PROTECTIVE_STOP if s.protective_stop else SAFETY_NORMAL,
            "safety_status": SAFETY_PROTECTIVE_STOP if s.protective_stop else SAFETY_NORMAL,
            "safety_status_bits": (1 << 2) if s.protective_stop else 1,
            "robot_status_bits": 1 | (2 if s.program_running else 0),
            "runtime_state": RUNTIME_PLAYING if s.program_running else RUNTIME_STOPPED,
            "actual_digital_output_bits": s.digital_out | (s.tool_digital_out << 16),
            "speed_scaling": s.speed_slider, "target_speed_fraction": s.speed_slider,
            "standard_analog_input0": sim.gripper_width() / GRIPPER_METRES_PER_VOLT,
            "actual_main_voltage": 48.0, "actual_robot_voltage": 48.0, "joint_temperatures": (30.0,) * 6,
        }
        values = []
        for name, kind in zip(names, kinds):
            if name in s.outputs:
                values.append(s.outputs[name])
            elif name in s.inputs:
                values.append(s.inputs[name])
            elif name in state:
                values.append(state[name])
            else:  # a variable the simulation does not model reads as zero
                fmt = rp.FORMATS[kind]
                zero = False if kind == "BOOL" else 0
                values.append((zero,) * int(fmt[0]) if fmt[0].isdigit() else zero)
        return values

    def apply_inputs(self, names: list[str], values: list) -> None:
        """Write one input package (variables ``names`` = ``values``) to the shared table; digital outputs under
        their masks, the speed slider, the gripper follows its digital output."""
        c = self.c
        with c.lock:
            s = c.state
            new = dict(zip(names, values))
            s.inputs.update(new)
            for mask_name, value_name, attr in (("standard_digital_output_mask", "standard_digital_output",
                                                 "digital_out"),
                                                ("tool_digital_output_mask", "tool_digital_output",
                                                 "tool_digital_out")):
                if mask_name in new and value_name in new and new[mask_name]:
                    mask, value = new[mask_name], new[value_name]
                    before = getattr(s, attr)
                    after = (before & ~mask) | (value & mask)
                    setattr(s, attr, after)
                    c.record(f"{value_name} mask={mask:#04x} value={value:#04x}")
            if "speed_slider_mask" in new and new["speed_slider_mask"]:
                s.speed_slider = float(new.get("speed_slider_fraction", s.speed_slider))
            c.sim.set_gripper(bool(s.digital_out >> c.gripper_output & 1))

    def serve(self, conn: socket.socket) -> None:
        c = self.c
        outputs: dict[int, tuple[list[str], list[str], float]] = {}
        inputs: dict[int, tuple[list[str], list[str]]] = {}
        streaming = threading.Event()
        send_lock = threading.Lock()

        def send(kind, payload=b""):
            with send_lock:
                conn.sendall(rp.frame(kind, payload))

        def stream():
            try:
                stream_outputs()
            except OSError:  # the client went away
                streaming.clear()

        def stream_outputs():
            next_time = {rid: time.monotonic() for rid in outputs}
            while not c.stopping.is_set() and streaming.is_set():
                now = time.monotonic()
                for rid, (names, types, freq) in list(outputs.items()):
                    if now >= next_time.get(rid, now):
                        with c.lock:
                            values = self.values(names, types)
                        send(rp.DATA_PACKAGE, bytes([rid]) + rp.pack_values(types, values))
                        next_time[rid] = max(next_time.get(rid, now) + 1 / freq, now)
                time.sleep(max(0.0, min(next_time.values(), default=now + 0.01) - time.monotonic()))

        try:
            while not c.stopping.is_set():
                kind, payload = rp.read_frame(conn)
                if kind == rp.REQUEST_PROTOCOL_VERSION:
                    send(rp.REQUEST_PROTOCOL_VERSION, bytes([1 if struct.unpack(">H", payload)[0] == 2 else 0]))
                elif kind == rp.GET_URCONTROL_VERSION:
                    send(rp.GET_URCONTROL_VERSION, struct.pack(">IIII", *CONTROLLER_VERSION))
                elif kind == rp.SETUP_OUTPUTS:
                    frequency = struct.unpack(">d", payload[:8])[0]
                    names = [n for n in payload[8:].decode().split(",") if n]  # ur-rtde ends the list with a comma
                    types = [rp.output_type(n) or "NOT_FOUND" for n in names]
                    rid = len(outputs) + 1 if "NOT_FOUND" not in types else 0
                    if rid:
                        outputs[rid] = (names, types, min(max(frequency, 1.0), c.max_frequency))
                    else:
                        unknown = [n for n, t in zip(names, types) if t == "NOT_FOUND"]
                        c.record(f"rtde output setup refused: unknown {unknown}")
                    send(rp.SETUP_OUTPUTS, bytes([rid]) + ",".join(types).encode())
                elif kind == rp.SETUP_INPUTS:
                    names = [n for n in payload.decode().split(",") if n]
                    with c.lock:  # a field another client has set up is IN_USE, as a UR controller answers
                        types = [rp.input_type(n) or "NOT_FOUND" if c.input_owners.get(n, conn) is conn
                                 else "IN_USE" for n in names]
                        rid = len(inputs) + 1 if not {"NOT_FOUND", "IN_USE"} & set(types) else 0
                        if rid:
                            inputs[rid] = (names, types)
                            c.input_owners.update({n: conn for n in names})
                    if not rid:
                        refused = [f"{n} ({t})" for n, t in zip(names, types) if t in ("NOT_FOUND", "IN_USE")]
                        c.record(f"rtde input setup refused: {', '.join(refused)}")
                    send(rp.SETUP_INPUTS, bytes([rid]) + ",".join(types).encode())
                elif kind == rp.START:
                    send(rp.START, b"\x01")
                    if outputs and not streaming.is_set():
                        streaming.set()
                        c.spawn(stream)
                elif kind == rp.PAUSE:
                    streaming.clear()
                    send(rp.PAUSE, b"\x01")
                elif kind == rp.DATA_PACKAGE:
                    rid = payload[0]
                    if rid in inputs:
                        names, types = inputs[rid]
                        self.apply_inputs(names, rp.unpack_values(types, payload[1:]))
                elif kind == rp.TEXT_MESSAGE:
                    pass
        finally:
            streaming.clear()
            with c.lock:  # this client's input fields are free again
                for name in [n for n, owner in c.input_owners.items() if owner is conn]:
                    del c.input_owners[name]
