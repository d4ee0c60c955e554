"""Declaring a node's start-up parameters: read-only, with a description."""
from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import ParameterDescriptor


def declare_startup(node, name: str, default: Any, text: str) -> Any:
    """Declare a read-only parameter of ``node`` described by ``text``; return its value."""
    return node.declare_parameter(
        name, default, ParameterDescriptor(description=text, read_only=True)).value
