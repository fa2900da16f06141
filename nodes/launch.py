"""ROS 2 launch files without ROS 2: the subset of ``launch`` / ``launch_ros`` our launch files use, and the
runner behind ``pegasus launch FILE [name:=value ...]``.

A launch file (``launch/*.launch.py``) imports LaunchDescription, DeclareLaunchArgument,
LaunchConfiguration and Node from the real packages when ROS 2 is installed (then ``ros2 launch`` runs
it) and from here otherwise, and defines ``generate_launch_description()``. The runner resolves the
declared arguments (defaults, ``name:=value`` overrides; an undeclared or invalid one is an error naming
the declared ones), builds every Node action's node in this process from ``nodes.<executable>``'s
``NODE_CLASS`` with its parameters (evaluated as launch_ros does) as overrides, each in a context of its own
on one shared graph, and spins them on one multi-threaded executor until a node whose action has
``on_exit=Shutdown()`` ends (``nodes.ros.finish``) or Ctrl-C; a node that ends without it just stops.
Where ROS 2 is installed the launch files get the real launch classes: run them with ``ros2 launch`` there.
"""

from __future__ import annotations

import importlib
import importlib.util
from dataclasses import dataclass, field
from pathlib import Path

from pegasus_gen.errors import PegasusError


@dataclass
class LaunchConfiguration:
    """The value of a launch argument, substituted when the launch runs."""

    variable_name: str


@dataclass
class ParameterValue:
    """launch_ros.parameter_descriptions.ParameterValue: ``value`` (a LaunchConfiguration or a literal) coerced
    to ``value_type`` (str, int, float, bool or typing.List of one of them; None: YAML rules)."""

    value: object
    value_type: object = None


@dataclass
class DeclareLaunchArgument:
    name: str
    default_value: str | None = None
    description: str = ""
    choices: list[str] | None = None


@dataclass
class Shutdown:
    """launch.actions.Shutdown: as a Node's ``on_exit``, the node's end ends the launch."""

    reason: str = ""


@dataclass
class LaunchConfigurationNotEquals:
    """launch.conditions.LaunchConfigurationNotEquals: true when the argument's value is not ``expected_value``."""

    launch_configuration_name: str
    expected_value: str | None

    def evaluate(self, arguments: dict[str, str]) -> bool:
        return arguments[self.launch_configuration_name] != self.expected_value


@dataclass
class Node:
    """launch_ros.actions.Node: ``executable`` names the module ``nodes.<executable>``; ``on_exit`` (Shutdown)
    ends the launch when the node ends; a ``condition`` that evaluates false leaves the node out."""

    package: str = "pegasus"
    executable: str = ""
    name: str | None = None
    parameters: list = field(default_factory=list)  # [dict]
    output: str = "screen"
    arguments: list = field(default_factory=list)
    on_exit: object = None
    condition: LaunchConfigurationNotEquals | None = None


class LaunchDescription:
    def __init__(self, entities=None):
        self.entities = list(entities or [])

    def add_action(self, action) -> None:
        self.entities.append(action)


def parse_overrides(items: list[str]) -> dict[str, str]:
    """``name:=value`` strings -> {name: value}; anything else is an error."""
    out = {}
    for item in items:
        if ":=" not in item:
            raise PegasusError(f"launch argument {item!r} is not of the form name:=value")
        name, value = item.split(":=", 1)
        out[name] = value
    return out


def launch_dir() -> Path:
    """The folder of the launch files installed with the package (``pegasus_launch``; ``launch/`` in the source)."""
    spec = importlib.util.find_spec("pegasus_launch")
    if spec is None or not spec.submodule_search_locations:
        raise PegasusError("the pegasus launch files are not installed (no package pegasus_launch)")
    return Path(next(iter(spec.submodule_search_locations)))


def installed_launch_files() -> list[str]:
    """Names of the installed ``*.launch.py`` files, sorted."""
    return sorted(p.name for p in launch_dir().glob("*.launch.py"))


def find_launch_file(file: str | Path) -> Path:
    """A launch file given as a path, or by the name of an installed one (``sim_pick_place.launch.py``)."""
    path = Path(file)
    if path.is_file():
        return path
    installed = launch_dir() / path.name
    if path.name == str(file) and installed.is_file():
        return installed
    raise PegasusError(f"{file}: no such launch file (installed: {', '.join(installed_launch_files())})")


def load_description(path: str | Path) -> LaunchDescription:
    """The LaunchDescription of a launch file (a path or an installed name); a file that is not Python, or
    does not compile, is a PegasusError."""
    path = find_launch_file(path)
    if path.suffix != ".py":
        raise PegasusError(f"{path}: not a launch file (a Python file, *.launch.py)")
    spec = importlib.util.spec_from_file_location(path.stem.replace(".", "_"), path)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except SyntaxError as exc:
        raise PegasusError(f"{path}: line {exc.lineno}: {exc.msg} (the launch file is not valid Python)") from None
    if not hasattr(module, "generate_launch_description"):
        raise PegasusError(f"{path}: has no generate_launch_description()")
    return module.generate_launch_description()


def resolve_arguments(description: LaunchDescription, overrides: dict[str, str]) -> dict[str, str]:
    """{argument: value} from the declarations and the overrides (clear errors for unknown, missing or
    out-of-choice values)."""
    declared = {e.name: e for e in description.entities if isinstance(e, DeclareLaunchArgument)}
    unknown = sorted(set(overrides) - set(declared))
    if unknown:
        raise PegasusError(f"unknown launch argument(s) {', '.join(unknown)} (declared: {', '.join(sorted(declared))})")
    values = {}
    for name, decl in declared.items():
        value = overrides.get(name, decl.default_value)
        if value is None:
            raise PegasusError(f"launch argument {name!r} has no default: give {name}:=VALUE ({decl.description})")
        if decl.choices is not None and value not in decl.choices:
            raise PegasusError(f"launch argument {name}:={value} is not one of {', '.join(decl.choices)}")
        values[name] = value
    return values


def parameter_value(name: str, value, arguments: dict[str, str]):
    """A Node action's parameter value as launch_ros evaluates it (``evaluate_parameter_dict``): a launch
    argument's text by YAML rules ('' stays a string; a list must be non-empty and of one type: a tuple);
    a ParameterValue coerced to its type as launch's ``coerce_to_type`` does (int and float from the text,
    lists by YAML with items of exactly that type); literal lists of numbers become floats."""
    try:
        if isinstance(value, ParameterValue):
            inner = value.value
            if not isinstance(inner, LaunchConfiguration):
                return parameter_value(name, inner, arguments)
            return _coerce(arguments[inner.variable_name], value.value_type)
        if isinstance(value, LaunchConfiguration):
            return _yaml_value(arguments[value.variable_name])
        if isinstance(value, (list, tuple)):
            if value and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
                return tuple(float(v) for v in value)
            if not value or not all(type(v) is type(value[0]) and type(v) in (bool, str) for v in value):
                raise ValueError("expected a non-empty list of one type (bool, int, float or str)")
            return tuple(value)
        if isinstance(value, (bool, int, float, str)):
            return value
        raise ValueError(f"a {type(value).__name__} is not a parameter value")
    except ValueError as exc:
        raise PegasusError(f"launch: parameter {name}: {exc}") from None


def _yaml_value(text: str):
    import yaml

    if text == "":
        return ""
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        raise ValueError(f"{text!r} is not YAML; a string parameter needs ParameterValue(..., value_type=str)")
    if type(value) in (bool, int, float, str):
        return value
    if isinstance(value, list) and value and type(value[0]) in (bool, int, float, str) \
            and all(type(v) is type(value[0]) for v in value):
        return tuple(value)
    raise ValueError(f"{text!r} is neither a scalar nor a non-empty list of one type (bool, int, float, str)")


def _coerce(text: str, value_type):
    import typing

    if value_type is None:
        return _yaml_value(text)
    is_list = typing.get_origin(value_type) in (list, typing.List)
    item = typing.get_args(value_type)[0] if is_list else value_type
    if item not in (str, int, float, bool):
        raise ValueError(f"value_type must be str, int, float, bool or a List of one, got {value_type}")
    if is_list:
        import yaml

        try:
            value = yaml.safe_load(text) if text else text
        except yaml.YAMLError:
            raise ValueError(f"{text!r} is not YAML") from None
        if not isinstance(value, list) or not all(isinstance(v, item) for v in value):
            raise ValueError(f"cannot convert {text!r} to a list of {item.__name__}")
        return tuple(value)
    if item is str:
        return text
    if item in (int, float):
        return item(text)
    value = _yaml_value(text)
    if not isinstance(value, bool):
        raise ValueError(f"cannot convert {text!r} to bool")
    return value


def build_nodes(description: LaunchDescription, arguments: dict[str, str], graph) -> list[tuple]:
    """[(node, its Node action)] of the description's Node actions, each node constructed with its parameters
    in a context of its own (on ``graph``, a stand-in Context: the nodes talk, and end, as separate
    processes do). If one cannot be built, those built before it are destroyed."""
    from nodes import compat

    built = []
    try:
        for entity in description.entities:
            if not isinstance(entity, Node) or (entity.condition and not entity.condition.evaluate(arguments)):
                continue
            try:
                module = importlib.import_module(f"nodes.{entity.executable}")
            except ModuleNotFoundError as exc:
                raise PegasusError(f"launch: no node executable {entity.executable!r} "
                                   f"(nodes.{entity.executable})") from exc
            params = {}
            for group in entity.parameters:
                params.update({k: parameter_value(k, v, arguments) for k, v in group.items()})
            context = compat.Context(graph=graph)
            compat.init(context=context)
            try:
                node = module.NODE_CLASS(context=context,
                                         parameter_overrides=[compat.Parameter(k, value=v) for k, v in params.items()])
            except compat.ParameterException as exc:  # a parameter of another type than the node declares
                raise PegasusError(f"launch: {entity.executable}: {exc}") from None
            built.append((node, entity))
    except BaseException:
        for node, _ in built:
            node.destroy_node()
        raise
    return built


def run(path: str | Path, overrides: list[str], timeout: float | None = None) -> list:
    """Run a launch file (see the module docstring); returns the nodes after they stopped."""
    import time

    from nodes import compat

    description = load_description(path)
    arguments = resolve_arguments(description, parse_overrides(overrides))
    graph = compat.Context()
    compat.init(context=graph)
    built = build_nodes(description, arguments, graph)
    executor = compat.MultiThreadedExecutor(context=graph)
    for node, _ in built:
        executor.add_node(node)
    t0 = time.monotonic()
    try:
        while graph.running:
            if timeout is not None and time.monotonic() - t0 > timeout:
                break
            executor.spin_once(timeout_sec=0.05)
            for node, action in [(n, a) for n, a in built if not n.context.running and n in executor.nodes]:
                executor.remove_node(node)  # the node's process has exited
                if isinstance(action.on_exit, Shutdown):
                    compat.shutdown(graph)
    finally:
        executor.shutdown()
        for node, _ in built:
            node.destroy_node()
            compat.try_shutdown(node.context)
        compat.try_shutdown(graph)
    return [node for node, _ in built]


def run_processes(path: str | Path, overrides: list[str], env: dict | None = None, timeout: float | None = None,
                  log_dir: str | Path | None = None) -> dict[str, int]:
    """Run a launch file as ``ros2 launch`` does, on the real rclpy: every Node action a process of its own
    (``nodes.<executable>``'s ``main`` under ``PEGASUS_ROS=rclpy``, its parameters in a params file), until a
    node whose action has ``on_exit=Shutdown()`` exits, every node has, or ``timeout`` seconds pass; then Ctrl-C
    (SIGINT) to the others. ``env``: more environment (``ROS_DOMAIN_ID``); ``log_dir``: each node's output in
    ``<executable>.log``. Returns {executable: exit code}."""
    import os
    import signal
    import subprocess
    import sys
    import tempfile
    import time

    import yaml

    description = load_description(path)
    arguments = resolve_arguments(description, parse_overrides(overrides))
    env = {**os.environ, "PEGASUS_ROS": "rclpy", **(env or {})}
    running, logs = [], []
    with tempfile.TemporaryDirectory(prefix="pegasus-launch-") as tmp:
        try:
            for entity in description.entities:
                if not isinstance(entity, Node) or (entity.condition and not entity.condition.evaluate(arguments)):
                    continue
                params = {}
                for group in entity.parameters:
                    params.update({k: parameter_value(k, v, arguments) for k, v in group.items()})
                params_file = Path(tmp) / f"{entity.executable}.yaml"
                params_file.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
                out = open(Path(log_dir) / f"{entity.executable}.log", "w") if log_dir else subprocess.DEVNULL
                logs.append(out)
                running.append((entity, subprocess.Popen(
                    [sys.executable, "-c", f"from nodes.{entity.executable} import main; main()", "--ros-args",
                     "--params-file", str(params_file)], env=env, stdout=out, stderr=subprocess.STDOUT)))
            t0 = time.monotonic()
            while not any(isinstance(entity.on_exit, Shutdown) and process.poll() is not None
                          for entity, process in running):
                if all(process.poll() is not None for _, process in running):
                    break
                if timeout is not None and time.monotonic() - t0 > timeout:
                    break
                time.sleep(0.2)
        finally:
            for _, process in running:
                if process.poll() is None:
                    process.send_signal(signal.SIGINT)
            for _, process in running:
                try:
                    process.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()
            for out in logs:
                if out is not subprocess.DEVNULL:
                    out.close()
    return {entity.executable: process.returncode for entity, process in running}
