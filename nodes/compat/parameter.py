"""rclpy.parameter and rcl_interfaces' parameter messages: typed parameters as rclpy types them."""

from __future__ import annotations

import array
from dataclasses import dataclass
from enum import IntEnum


class Parameter:
    """rclpy.parameter.Parameter: a name, a type (``Parameter.Type``, from the value unless given) and a value
    of that type (an int is not a DOUBLE; arrays are lists or tuples of one element type; an empty list is
    a BYTE_ARRAY)."""

    class Type(IntEnum):
        NOT_SET = 0
        BOOL = 1
        INTEGER = 2
        DOUBLE = 3
        STRING = 4
        BYTE_ARRAY = 5
        BOOL_ARRAY = 6
        INTEGER_ARRAY = 7
        DOUBLE_ARRAY = 8
        STRING_ARRAY = 9

        @classmethod
        def from_parameter_value(cls, value) -> "Parameter.Type":
            """The first type, in rclpy's order (bool before int; an empty list is a BYTE_ARRAY), that holds
            ``value``; TypeError when none does."""
            if value is None:
                return cls.NOT_SET
            kinds = _ARRAY_ITEMS if isinstance(value, (list, tuple, array.array)) else _SCALARS
            kind = next((kind for kind in kinds if cls(kind).check(value)), None)
            if kind is None:
                raise TypeError(f"The given value is not one of the allowed types '{value}'.")
            return cls(kind)

        def check(self, value) -> bool:
            """Whether ``value`` can be held as this type (rclpy's rule: a bool is an int here)."""
            if self == Parameter.Type.NOT_SET:
                return value is None
            if self in _SCALARS:
                return isinstance(value, _SCALARS[self])
            return isinstance(value, (list, tuple, array.array)) and all(isinstance(v, _ARRAY_ITEMS[self])
                                                                         for v in value)

    def __init__(self, name: str, type_: "Parameter.Type | None" = None, value=None):
        if type_ is None:
            type_ = Parameter.Type.from_parameter_value(value)
        if not isinstance(type_, Parameter.Type):
            raise TypeError(f"type_ must be a Parameter.Type, got {type_!r}")
        if not type_.check(value):
            raise ValueError(f"Type {type_} and value {value} do not agree")
        self._name, self._type, self._value = name, type_, value

    @property
    def name(self) -> str:
        return self._name

    @property
    def value(self):
        return self._value

    @property
    def type_(self) -> "Parameter.Type":
        return self._type

    def get_parameter_value(self) -> "ParameterValue":
        return ParameterValue.of(self._type, self._value)


# Parameter.Type -> the Python type of the value (of each item, for arrays), in rclpy's order of inference
_SCALARS = {Parameter.Type.BOOL: bool, Parameter.Type.INTEGER: int, Parameter.Type.DOUBLE: float,
            Parameter.Type.STRING: str}
_ARRAY_ITEMS = {Parameter.Type.BYTE_ARRAY: bytes, Parameter.Type.BOOL_ARRAY: bool, Parameter.Type.INTEGER_ARRAY: int,
                Parameter.Type.DOUBLE_ARRAY: float, Parameter.Type.STRING_ARRAY: str}


@dataclass
class ParameterValue:
    """rcl_interfaces.msg.ParameterValue: the field of the value's type is set, the others keep defaults."""

    type: int = 0
    bool_value: bool = False
    integer_value: int = 0
    double_value: float = 0.0
    string_value: str = ""
    byte_array_value: tuple = ()
    bool_array_value: tuple = ()
    integer_array_value: tuple = ()
    double_array_value: tuple = ()
    string_array_value: tuple = ()

    @classmethod
    def of(cls, type_: Parameter.Type, value) -> "ParameterValue":
        if type_ == Parameter.Type.NOT_SET:
            return cls()
        return cls(**{"type": int(type_), f"{type_.name.lower()}_value": value})


@dataclass
class SetParametersResult:
    """rcl_interfaces.msg.SetParametersResult"""

    successful: bool = False
    reason: str = ""


@dataclass
class ParameterDescriptor:
    """rcl_interfaces.msg.ParameterDescriptor, the fields the stand-in honours."""

    name: str = ""
    type: int = 0
    description: str = ""
    read_only: bool = False
    dynamic_typing: bool = False
