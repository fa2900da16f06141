"""rclpy.exceptions: what the stand-in raises where rclpy raises it."""

from __future__ import annotations

from nodes.compat.parameter import Parameter


class RCLError(RuntimeError):
    """rclpy._rclpy_pybind11.RCLError: what rcl refuses (a negative timer period, a second type on a topic)."""


class ExternalShutdownException(Exception):
    """rclpy.executors.ExternalShutdownException: real rclpy's spin raises it when a signal shut the context
    down; the stand-in's spin just returns."""


class ParameterException(Exception):
    """rclpy.exceptions.ParameterException: the message, then ``: `` and the parameter(s)."""

    def __init__(self, message: str, name):
        super().__init__(f"{message}: {name}")
        self.parameter_name = name


class ParameterNotDeclaredException(ParameterException):
    def __init__(self, name):
        super().__init__("Invalid access to undeclared parameter(s)", name)


class ParameterAlreadyDeclaredException(ParameterException):
    def __init__(self, name):
        super().__init__("Parameter(s) already declared", name)


class InvalidParameterTypeException(ParameterException):
    """A value of another type than the parameter's static type (rclpy.exceptions)."""

    def __init__(self, desired_parameter: Parameter, expected_type: str):
        value = desired_parameter.value
        super().__init__(f"Trying to set parameter '{desired_parameter.name}' to '{value}' of type "
                         f"'{Parameter.Type.from_parameter_value(value).name}', expecting type '{expected_type}'",
                         desired_parameter.name)


class ParameterUninitializedException(ParameterException):
    def __init__(self, name: str):
        super().__init__(f"The parameter '{name}' is not initialized", name)




class InvalidTopicNameException(Exception):
    """rclpy.exceptions.InvalidTopicNameException"""
