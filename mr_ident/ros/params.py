# SPDX-License-Identifier: Apache-2.0
"""The node's parameters: the fields of IdentConfig and the node's own, declared, read back.

Every field of :class:`~mr_ident.io.config.IdentConfig` is a parameter with its description
and range; what the node reads only when it is configured (the sources, the labels' topic)
and its own switches are ``read_only``. Values are validated through IdentConfig (one rule,
one place): on every set and at configure. This module only speaks rclpy's parameter types.
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
)
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..io.config import PARAMETERS, IdentConfig

#: The node's own parameters (not identification settings): name -> (default, description).
NODE_PARAMETERS: dict[str, tuple[bool, str]] = {
    "autostart": (
        False,
        "configure and activate at start; false (default, as a managed node): wait "
        "unconfigured for lifecycle transitions (the launch file's autostart, a lifecycle "
        "manager, ros2 lifecycle set)",
    ),
    "legacy_array_topics": (
        False,
        "also publish each estimate as the Float64MultiArray topics of earlier versions "
        "(~/frequencies, ~/plant_frf, ...) beside ~/estimate",
    ),
}

#: Read once, at start: a change needs a new node (rclpy refuses the set).
READ_ONLY = frozenset(
    {"r_source", "u_source", "y_source", "excitation_index_topic", *NODE_PARAMETERS}
)


def descriptor(name: str, default: Any) -> ParameterDescriptor:
    """The descriptor of parameter ``name``: its description, type, range, read-only."""
    spec = PARAMETERS.get(name)
    text = spec.description if spec is not None else NODE_PARAMETERS[name][1]
    d = ParameterDescriptor(name=name, description=text, read_only=name in READ_ONLY)
    low = (spec.low if spec is not None else None) or 0.0
    high = (spec.high if spec is not None else None) or 0.0
    if isinstance(default, bool):
        d.type = ParameterType.PARAMETER_BOOL
    elif isinstance(default, float):
        d.type = ParameterType.PARAMETER_DOUBLE
        d.floating_point_range = [
            FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)
        ]
    elif isinstance(default, int):
        d.type = ParameterType.PARAMETER_INTEGER
        d.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
    elif isinstance(default, str):
        d.type = ParameterType.PARAMETER_STRING
    elif name.endswith("_source"):
        d.type = ParameterType.PARAMETER_STRING_ARRAY
    else:
        d.type = ParameterType.PARAMETER_DOUBLE_ARRAY
    return d


def declare(node: Node) -> None:
    """Declare every field of IdentConfig and the node's own parameters on ``node``.

    Every parameter has a value (``ros2 param dump`` and GetParameters list them all): an
    array is declared with its type, and when no override gave it a value it is set empty,
    then made read-only where it is. Values are not validated here (see :func:`read`): a
    node with a bad params file still comes up, unconfigured, and says why its configure
    fails.
    """
    for key, default in IdentConfig().as_dict().items():
        if not isinstance(default, list):
            node.declare_parameter(key, default, descriptor(key, default))
            continue
        kind = (
            Parameter.Type.STRING_ARRAY if key.endswith("_source") else Parameter.Type.DOUBLE_ARRAY
        )
        final = descriptor(key, default)
        writable = ParameterDescriptor()
        writable.name, writable.type, writable.description = (
            final.name,
            final.type,
            final.description,
        )
        node.declare_parameter(key, kind, writable)
        if node.get_parameter_or(key).type_ == Parameter.Type.NOT_SET:
            node.set_parameters([Parameter(key, kind, [])])
        node.set_descriptor(key, final)
    for key, (default, _) in NODE_PARAMETERS.items():
        node.declare_parameter(key, default, descriptor(key, default))


def read(node: Node) -> IdentConfig:
    """The config the node's current parameter values give; ConfigError when not valid."""
    values = []
    for name in PARAMETERS:
        try:
            values.append(node.get_parameter(name))
        except ParameterUninitializedException:  # an array declared without a value: empty
            values.append(Parameter(name, Parameter.Type.NOT_SET, None))
    return IdentConfig().replace(**changes(values))


def flag(node: Node, name: str) -> bool:
    """One of the node's own switches (:data:`NODE_PARAMETERS`)."""
    return bool(node.get_parameter(name).value)


def changes(params: list[Parameter]) -> dict[str, Any]:
    """The IdentConfig fields a parameter set changes (arrays as tuples; others ignored)."""
    out = {}
    for p in params:
        if p.name in PARAMETERS:
            v = p.value
            if p.type_ in (
                Parameter.Type.DOUBLE_ARRAY,
                Parameter.Type.STRING_ARRAY,
                Parameter.Type.NOT_SET,
            ) or isinstance(v, (list, tuple)):
                v = () if v is None else tuple(v)
            out[p.name] = v
    return out
