"""The node's parameters: the fields of IdentConfig, declared with their ranges, read back.

Every set is validated through :class:`~mr_ident.io.config.IdentConfig` (one rule, one
place); this module only speaks rclpy's parameter types.
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..io.config import PARAMETERS, IdentConfig


def descriptor(name: str, default: Any) -> ParameterDescriptor:
    """The descriptor of parameter ``name``: its description, type and range."""
    spec = PARAMETERS[name]
    d = ParameterDescriptor(name=name, description=spec.description)
    low, high = (spec.low or 0.0), (spec.high or 0.0)
    if isinstance(default, float):
        d.type = ParameterType.PARAMETER_DOUBLE
        d.floating_point_range = [
            FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)
        ]
    elif isinstance(default, int):
        d.type = ParameterType.PARAMETER_INTEGER
        d.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
    elif isinstance(default, str):
        d.type = ParameterType.PARAMETER_STRING
    else:
        d.type = ParameterType.PARAMETER_DOUBLE_ARRAY
    return d


def declare(node: Node) -> IdentConfig:
    """Declare every field of IdentConfig on ``node``; the config its values give.

    Raises ConfigError when the values (a params file, overrides) are not valid.
    """
    values = {}
    for key, default in IdentConfig().as_dict().items():
        if isinstance(default, list):
            kind = (
                Parameter.Type.STRING_ARRAY
                if key.endswith("_source")
                else Parameter.Type.DOUBLE_ARRAY
            )
            p = node.declare_parameter(key, kind, descriptor(key, default))
            values[key] = tuple(p.value) if p.value is not None else ()
        else:
            values[key] = node.declare_parameter(key, default, descriptor(key, default)).value
    return IdentConfig().replace(**values)


def changes(params: list[Parameter]) -> dict[str, Any]:
    """The IdentConfig fields a parameter set changes (arrays as tuples; others ignored)."""
    out = {}
    for p in params:
        if p.name in PARAMETERS:
            v = p.value
            if p.type_ in (
                Parameter.Type.DOUBLE_ARRAY,
                Parameter.Type.STRING_ARRAY,
            ) or isinstance(v, (list, tuple)):
                v = () if v is None else tuple(v)
            out[p.name] = v
    return out
