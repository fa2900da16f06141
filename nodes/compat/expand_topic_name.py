"""rclpy.expand_topic_name: a node's topic or service name made fully qualified."""

from __future__ import annotations

import re

from nodes.compat.exceptions import InvalidTopicNameException

_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"


def expand_topic_name(name: str, node_name: str, namespace: str) -> str:
    """The fully qualified name of topic or service ``name`` as ROS 2 (rcl) expands it: relative names go
    under the node's namespace, ``~`` is the node's own, ``{node}`` / ``{ns}`` / ``{namespace}`` are
    substituted (another substitution is a ValueError); InvalidTopicNameException when it breaks ROS 2's name
    rules (tokens of letters, digits and underscores not starting with a digit, no empty token, no trailing
    ``/``, ``~`` only first and followed by ``/``)."""
    base = "/" + namespace.strip("/") if namespace.strip("/") else ""
    for sub in re.findall(r"\{[^{}]*\}", name):
        if sub not in ("{node}", "{ns}", "{namespace}"):
            raise ValueError(f"topic name {name!r} is invalid: unknown substitution: {sub}")
    expanded = name.replace("{node}", node_name).replace("{ns}", base or "/").replace("{namespace}", base or "/")
    if expanded == "~" or expanded.startswith("~/"):
        full = f"{base}/{node_name}{expanded[1:]}"
    else:
        full = expanded if expanded.startswith("/") else f"{base}/{expanded}"
    if not re.fullmatch(f"(/{_TOKEN})+", full):
        raise InvalidTopicNameException(f"Invalid topic name: {name!r} (expanded: {full!r}) breaks ROS 2's rules")
    return full
