"""The RTDE wire protocol (version 2) as a UR controller serves it on port 30004: frames, variable types and
the data packages of recipes. Used by the simulated controller; ur-rtde is the client.

Frame: big-endian [uint16 size (whole frame)][uint8 type][payload]. Types used: 'V' protocol version
(client: uint16 version; server: uint8 accepted), 'v' controller version (server: 4 x uint32), 'O' output
setup (client: float64 frequency + comma-separated names; server: uint8 recipe id + comma-separated
types), 'I' input setup (client: names; server: recipe id + types), 'S' start / 'P' pause (server:
uint8 accepted), 'U' data (uint8 recipe id + the values in recipe order), 'M' text message.
"""

from __future__ import annotations

import re
import socket
import struct

HEADER = struct.Struct(">HB")
REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
SETUP_OUTPUTS = ord("O")
SETUP_INPUTS = ord("I")
START = ord("S")
PAUSE = ord("P")

FORMATS = {"BOOL": "?", "UINT8": "B", "UINT32": "I", "UINT64": "Q", "INT32": "i", "DOUBLE": "d",
           "VECTOR3D": "3d", "VECTOR6D": "6d", "VECTOR6INT32": "6i", "VECTOR6UINT32": "6I"}

# Controller outputs (UR's RTDE guide), name -> type; registers are matched by pattern below.
OUTPUT_TYPES = {
    "timestamp": "DOUBLE", "target_q": "VECTOR6D", "target_qd": "VECTOR6D", "target_qdd": "VECTOR6D",
    "target_current": "VECTOR6D", "target_moment": "VECTOR6D", "actual_q": "VECTOR6D", "actual_qd": "VECTOR6D",
    "actual_current": "VECTOR6D", "actual_current_window": "VECTOR6D", "joint_control_output": "VECTOR6D",
    "actual_TCP_pose": "VECTOR6D", "actual_TCP_speed": "VECTOR6D", "actual_TCP_force": "VECTOR6D",
    "target_TCP_pose": "VECTOR6D", "target_TCP_speed": "VECTOR6D", "actual_digital_input_bits": "UINT64",
    "joint_temperatures": "VECTOR6D", "actual_execution_time": "DOUBLE", "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32", "safety_mode": "INT32", "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D", "speed_scaling": "DOUBLE", "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE", "actual_main_voltage": "DOUBLE", "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE", "actual_joint_voltage": "VECTOR6D", "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32", "elbow_position": "VECTOR3D", "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32", "safety_status_bits": "UINT32", "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE", "standard_analog_input1": "DOUBLE", "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE", "io_current": "DOUBLE", "euromap67_input_bits": "UINT32",
    "euromap67_output_bits": "UINT32", "euromap67_24V_voltage": "DOUBLE", "euromap67_24V_current": "DOUBLE",
    "tool_mode": "UINT32", "tool_analog_input_types": "UINT32", "tool_analog_input0": "DOUBLE",
    "tool_analog_input1": "DOUBLE", "tool_output_voltage": "INT32", "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE", "tcp_force_scalar": "DOUBLE", "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32", "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32", "tool_output_mode": "UINT8", "tool_digital_output0_mode": "UINT8",
    "tool_digital_output1_mode": "UINT8", "payload": "DOUBLE", "payload_cog": "VECTOR3D",
    "payload_inertia": "VECTOR6D", "script_control_line": "UINT32", "ft_raw_wrench": "VECTOR6D",
    "joint_position_deviation_ratio": "DOUBLE", "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "UINT32", "tcp_offset": "VECTOR6D", "actual_joint_torques": "VECTOR6D",
}

# Controller inputs a client may set, name -> type.
INPUT_TYPES = {
    "speed_slider_mask": "UINT32", "speed_slider_fraction": "DOUBLE", "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8", "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8", "tool_digital_output_mask": "UINT8", "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8", "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE", "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32", "input_bit_registers32_to_63": "UINT32",
    "external_force_torque": "VECTOR6D",
}

_REGISTER = re.compile(r"^(input|output)_(int|double|bit)_register_(\d+)$")


def register_type(name: str) -> str | None:
    """The type of ``input_int_register_N`` / ``output_double_register_N`` / ``..._bit_register_N`` names."""
    m = _REGISTER.match(name)
    if m is None:
        return None
    kind, index = m.group(2), int(m.group(3))
    if kind == "bit":
        return "BOOL" if 64 <= index <= 127 else None
    return ("INT32" if kind == "int" else "DOUBLE") if index <= 47 else None


def output_type(name: str) -> str | None:
    """Type of an output variable (inputs and input registers can be read back as outputs), None if unknown."""
    return OUTPUT_TYPES.get(name) or INPUT_TYPES.get(name) or register_type(name)


def input_type(name: str) -> str | None:
    """Type of a variable a client may write, None if it may not."""
    if name in INPUT_TYPES:
        return INPUT_TYPES[name]
    return register_type(name) if name.startswith("input_") else None


def frame(kind: int, payload: bytes = b"") -> bytes:
    return HEADER.pack(HEADER.size + len(payload), kind) + payload


def read_frame(sock: socket.socket) -> tuple[int, bytes]:
    """(type, payload) of the next frame; ConnectionError when the peer closes."""
    header = _read_exact(sock, HEADER.size)
    size, kind = HEADER.unpack(header)
    return kind, _read_exact(sock, size - HEADER.size)


def _read_exact(sock: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise ConnectionError("peer closed the connection")
        data += chunk
    return data


def pack_values(types: list[str], values: list) -> bytes:
    """Big-endian values in recipe order; vectors as sequences."""
    out = b""
    for t, v in zip(types, values):
        fmt = FORMATS[t]
        out += struct.pack(">" + fmt, *(v if fmt[0].isdigit() else [v]))
    return out


def unpack_values(types: list[str], data: bytes) -> list:
    """Inverse of ``pack_values``: a list of scalars and tuples."""
    values, offset = [], 0
    for t in types:
        fmt = struct.Struct(">" + FORMATS[t])
        v = fmt.unpack_from(data, offset)
        offset += fmt.size
        values.append(v if FORMATS[t][0].isdigit() else v[0])
    return values
