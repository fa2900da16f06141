"""Message classes of the stand-in layer, generated from the ROS 2 Humble interface definitions that the
``rosbags`` package ships (vision_msgs and std_srvs/Trigger, which it lacks, from their definitions below).
``nodes.ros`` exports the real ROS 2 classes instead when rclpy is installed; ``nodes.conversions`` converts
either to and from numpy.

An instance behaves as rosidl's generated Python class does: keyword-only constructor that refuses unknown
fields, every field checked on assignment (AssertionError, as rosidl raises, for a wrong type or an integer
out of range: an ``int`` is no ``float64``, a numpy integer is no ``int``), fixed-size numeric arrays held as numpy
arrays of the field's dtype, numeric sequences as ``array.array``, ``uint8[]`` included (``Image.data``).
"""

from __future__ import annotations

import array
import collections.abc
import math

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Nodetype

# vision_msgs 4 (Humble) and std_srvs, as their .msg/.srv files define them
EXTRA_DEFINITIONS = {
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score",
    "vision_msgs/msg/ObjectHypothesisWithPose": "ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose",
    "vision_msgs/msg/BoundingBox3D": "geometry_msgs/Pose center\ngeometry_msgs/Vector3 size",
    "vision_msgs/msg/Detection3D": "std_msgs/Header header\nObjectHypothesisWithPose[] results\nBoundingBox3D bbox\n"
                                   "string id",
    "vision_msgs/msg/Detection3DArray": "std_msgs/Header header\nDetection3D[] detections",
    "std_srvs/srv/Trigger_Request": "",
    "std_srvs/srv/Trigger_Response": "bool success\nstring message",
}
# default values the definitions give (rosbags keeps no defaults): {(type name, field): value}
DEFAULTS = {("geometry_msgs/msg/Quaternion", "w"): 1.0}

STORE = get_typestore(Stores.ROS2_HUMBLE)
for _name, _text in EXTRA_DEFINITIONS.items():
    # under the name given (rosbags would file a service's part as std_srvs/srv/msg/...)
    STORE.register({_name: next(iter(get_types_from_msg(_text, _name).values())) if _text else ([], [])})

_INT_RANGES = {"int8": (-2**7, 2**7 - 1), "uint8": (0, 2**8 - 1), "byte": (0, 2**8 - 1), "char": (0, 2**8 - 1),
               "int16": (-2**15, 2**15 - 1), "uint16": (0, 2**16 - 1), "int32": (-2**31, 2**31 - 1),
               "uint32": (0, 2**32 - 1), "int64": (-2**63, 2**63 - 1), "uint64": (0, 2**64 - 1)}
_FLOATS = {"float32": np.float32, "float64": np.float64}
_FLOAT32_MAX = 3.402823466e38
# rosbags' base type -> rosidl's name of it (get_fields_and_field_types)
_ROSIDL_NAMES = {"bool": "boolean", "byte": "octet", "char": "uint8", "float32": "float", "float64": "double"}
_TYPECODES = {"int8": "b", "uint8": "B", "byte": "B", "char": "B", "int16": "h", "uint16": "H", "int32": "i",
              "uint32": "I", "int64": "q", "uint64": "Q", "float32": "f", "float64": "d"}
_CLASSES: dict[str, type] = {}


def _check(ok: bool, cls: str, field: str, expected: str) -> None:
    if not ok:
        raise AssertionError(f"The '{field}' field of {cls} must be {expected}")


def _is_sequence(value) -> bool:
    return isinstance(value, (collections.abc.Sequence, collections.abc.Set, collections.UserList)) and not (
        isinstance(value, (str, collections.UserString)))


class _Field:
    """One field's rules, from its rosbags definition ((Nodetype, details))."""

    def __init__(self, owner: str, name: str, definition):
        self.owner, self.name = owner, name
        kind, details = definition
        self.kind = kind
        if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            (self.item_kind, self.item), self.size = details[0], details[1]
        else:
            self.item_kind, self.item, self.size = kind, details, 0
        self.base = self.item[0] if self.item_kind == Nodetype.BASE else None
        self.bound = self.item[1] if self.base == "string" else 0

    def item_ok(self, value) -> bool:
        if self.item_kind == Nodetype.NAME:
            return isinstance(value, message_class(self.item))
        if self.base == "bool":
            return isinstance(value, bool)
        if self.base == "byte" and self.kind == Nodetype.BASE:  # rosidl's octet: one byte as bytes
            return isinstance(value, bytes) and len(value) == 1
        if self.base == "string":
            return isinstance(value, str) and (not self.bound or len(value) <= self.bound)
        if self.base in _FLOATS:  # a float32 holds at most 3.4e38 in magnitude (or inf), as rosidl checks it
            return isinstance(value, float) and (
                self.base == "float64" or not (value < -_FLOAT32_MAX or value > _FLOAT32_MAX) or math.isinf(value))
        low, high = _INT_RANGES[self.base]
        return isinstance(value, int) and low <= value <= high  # a bool is an int, as rosidl sees it

    def rosidl_type(self) -> str:
        """The field's type as rosidl's ``get_fields_and_field_types`` spells it (``double[9]``,
        ``sequence<uint8>``, ``std_msgs/Header``)."""
        if self.item_kind == Nodetype.NAME:
            package, _, short = self.item.split("/")
            item = f"{package}/{short}"
        elif self.base == "string":
            item = f"string<{self.bound}>" if self.bound else "string"
        else:
            item = _ROSIDL_NAMES.get(self.base, self.base)
        if self.kind == Nodetype.ARRAY:
            return f"{item}[{self.size}]"
        if self.kind == Nodetype.SEQUENCE:
            return f"sequence<{item}, {self.size}>" if self.size else f"sequence<{item}>"
        return item

    def describe(self) -> str:
        item = self.item if self.item_kind == Nodetype.NAME else self.base
        if self.kind == Nodetype.ARRAY:
            return f"a sequence of {self.size} values of type {item}"
        if self.kind == Nodetype.SEQUENCE:
            return f"a sequence of values of type {item}"
        return f"of type {item}" + (f" (at most {self.bound} characters)" if self.bound else "")

    def default(self):
        if self.kind == Nodetype.ARRAY:
            if self.base in _TYPECODES:
                return np.zeros(self.size, dtype=np.dtype(self.base if self.base in _FLOATS else _TYPECODES[self.base]))
            return [self._scalar_default() for _ in range(self.size)]
        if self.kind == Nodetype.SEQUENCE:
            return array.array(_TYPECODES[self.base]) if self.base in _TYPECODES else []
        return DEFAULTS.get((self.owner, self.name), self._scalar_default())

    def _scalar_default(self):
        if self.item_kind == Nodetype.NAME:
            return message_class(self.item)()
        if self.base == "byte" and self.kind == Nodetype.BASE:
            return b"\x00"
        return {"bool": False, "string": ""}.get(self.base, 0.0 if self.base in _FLOATS else 0)

    def convert(self, value):
        """``value`` as stored, or AssertionError."""
        check = lambda ok: _check(ok, self.owner, self.name, self.describe())  # noqa: E731
        if self.kind == Nodetype.BASE or self.kind == Nodetype.NAME:
            check(self.item_ok(value))
            return value
        numeric = self.base in _TYPECODES
        if self.kind == Nodetype.ARRAY and numeric and isinstance(value, np.ndarray):
            check(value.dtype == self.default().dtype and value.size == self.size)
            return value
        if self.kind == Nodetype.SEQUENCE and numeric and isinstance(value, array.array):
            check(value.typecode == _TYPECODES[self.base])
            return value
        check(_is_sequence(value) and (self.kind != Nodetype.ARRAY or len(value) == self.size)
              and all(self.item_ok(v) for v in value))
        if numeric:
            return (np.array(value, dtype=self.default().dtype) if self.kind == Nodetype.ARRAY
                    else array.array(_TYPECODES[self.base], value))
        return list(value)


def _make_class(type_name: str) -> type:
    package, _, short = type_name.split("/")
    fields = [_Field(type_name, name, definition) for name, definition in STORE.fielddefs[type_name][1]]
    by_name = {f.name: f for f in fields}

    def __init__(self, check_fields=None, **kwargs):
        # check_fields: accepted as rosidl's classes accept it; the stand-in checks every field always (rosidl
        # checks only with check_fields=True or ROS_PYTHON_CHECK_FIELDS=1, which nodes.ros sets for real ROS 2)
        unknown = sorted(set(kwargs) - set(by_name))
        if unknown:
            raise AssertionError(f"Invalid arguments passed to constructor: {', '.join(unknown)}")
        for f in fields:
            setattr(self, f.name, kwargs[f.name] if f.name in kwargs else f.default())

    def __eq__(self, other):
        if not isinstance(other, self.__class__):
            return False
        return all(np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b
                   for a, b in ((getattr(self, n), getattr(other, n)) for n in by_name))

    def __repr__(self):
        return f"{package}.msg.{short}({', '.join(f'{n}={getattr(self, n)!r}' for n in by_name)})"

    def make_property(f: _Field):
        slot = "_" + f.name

        def setter(self, value):
            setattr(self, slot, f.convert(value))
        return property(lambda self: getattr(self, slot), setter)

    def get_fields_and_field_types(cls):
        return {f.name: f.rosidl_type() for f in fields}

    namespace = {"__slots__": tuple("_" + n for n in by_name), "__init__": __init__, "__eq__": __eq__,
                 "get_fields_and_field_types": classmethod(get_fields_and_field_types),
                 "__hash__": None, "__repr__": __repr__, "TYPE_NAME": type_name,
                 "__doc__": f"{type_name} (stand-in, fields checked on assignment)"}
    namespace.update({f.name: make_property(f) for f in fields})
    return type(short, (), namespace)


def message_class(type_name: str) -> type:
    """The stand-in class of a ROS 2 interface type, e.g. ``"sensor_msgs/msg/Image"`` (made once)."""
    if type_name not in _CLASSES:
        if type_name not in STORE.fielddefs:
            raise LookupError(f"no ROS 2 message definition {type_name!r}")
        _CLASSES[type_name] = _make_class(type_name)
    return _CLASSES[type_name]


def type_name(message_type: type) -> str:
    """``"sensor_msgs/msg/Image"`` of a stand-in class (as ``ros2 topic list -t`` shows it)."""
    return message_type.TYPE_NAME


def to_rosbags(msg):
    """``msg`` (a stand-in instance) as the rosbags typestore's instance of its type (numpy for every numeric
    array), which ``STORE.serialize_cdr`` writes."""
    cls = STORE.types[msg.TYPE_NAME]
    values = {}
    for name, (kind, details) in STORE.fielddefs[msg.TYPE_NAME][1]:
        value = getattr(msg, name)
        if kind == Nodetype.BASE and details[0] == "byte":
            value = value[0]
        elif kind == Nodetype.NAME:
            value = to_rosbags(value)
        elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            item_kind, item = details[0]
            if item_kind == Nodetype.NAME:
                value = [to_rosbags(v) for v in value]
            elif item[0] in _TYPECODES:
                value = np.asarray(value, dtype=np.dtype(item[0] if item[0] in _FLOATS else _TYPECODES[item[0]]))
            elif item[0] == "bool":  # rosbags writes bool arrays from numpy
                value = np.asarray(value, dtype=bool)
            else:
                value = list(value)
        values[name] = value
    return cls(**values)


def from_rosbags(instance):
    """The stand-in message of a rosbags typestore instance (the inverse of ``to_rosbags``)."""
    values = {}
    for name, (kind, details) in STORE.fielddefs[instance.__msgtype__][1]:
        value = getattr(instance, name)
        if kind == Nodetype.BASE and details[0] == "byte":
            value = bytes([value])
        elif kind == Nodetype.NAME:
            value = from_rosbags(value)
        elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            item_kind, item = details[0]
            if item_kind == Nodetype.NAME:
                value = [from_rosbags(v) for v in value]
            elif kind == Nodetype.SEQUENCE and item[0] in _TYPECODES:
                value = array.array(_TYPECODES[item[0]], np.ascontiguousarray(value).tobytes())
            elif item[0] not in _TYPECODES:
                value = value.tolist() if isinstance(value, np.ndarray) else list(value)  # bool[]: numpy here
        values[name] = value
    return message_class(instance.__msgtype__)(**values)


def serialize(msg) -> bytes:
    """``msg`` in CDR, the bytes ``rclpy.serialization.serialize_message`` gives and rosbag2 stores."""
    return bytes(STORE.serialize_cdr(to_rosbags(msg), msg.TYPE_NAME))


def deserialize(data: bytes, type_name: str):
    """The stand-in message of type ``type_name`` in CDR ``data``."""
    return from_rosbags(STORE.deserialize_cdr(data, type_name))


Time = message_class("builtin_interfaces/msg/Time")
Header = message_class("std_msgs/msg/Header")
String = message_class("std_msgs/msg/String")
Image = message_class("sensor_msgs/msg/Image")
CameraInfo = message_class("sensor_msgs/msg/CameraInfo")
Pose = message_class("geometry_msgs/msg/Pose")
PoseStamped = message_class("geometry_msgs/msg/PoseStamped")
TransformStamped = message_class("geometry_msgs/msg/TransformStamped")
TFMessage = message_class("tf2_msgs/msg/TFMessage")
ObjectHypothesisWithPose = message_class("vision_msgs/msg/ObjectHypothesisWithPose")
Detection3D = message_class("vision_msgs/msg/Detection3D")
Detection3DArray = message_class("vision_msgs/msg/Detection3DArray")


class Trigger:  # std_srvs/srv/Trigger
    Request = message_class("std_srvs/srv/Trigger_Request")
    Response = message_class("std_srvs/srv/Trigger_Response")
