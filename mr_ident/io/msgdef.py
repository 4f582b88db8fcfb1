# SPDX-License-Identifier: Apache-2.0
"""ROS 2 message definitions (``ros2msg``): the schema text a bag embeds, parsed.

A bag written by rosbag2 (MCAP storage), ``rosbags`` or ``mr-ident record`` carries, per
type, the type's ``.msg`` text followed by every nested type's, each after a line of 80
``=`` and ``MSG: pkg/Type``. :func:`parse_schema` turns that into a :class:`Registry`:
enough to walk CDR data of any type, ``control_msgs`` and ``pal_statistics_msgs``
included, with no package installed. :func:`installed_schema` builds the same text from
the ``.msg`` files of an installed ROS environment (the live node).
"""

from __future__ import annotations

import json
import os
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..errors import DataError, MrIdentError

#: Primitive types and their size in bytes (strings are length-prefixed, size 0 here).
PRIMITIVES: dict[str, int] = {
    "bool": 1, "byte": 1, "char": 1, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2,
    "int32": 4, "uint32": 4, "int64": 8, "uint64": 8, "float32": 4, "float64": 8,
    "string": 0, "wstring": 0,
}  # fmt: skip
#: NumPy dtype (little endian) of each fixed-size primitive.
DTYPES: dict[str, str] = {
    "bool": "u1", "byte": "u1", "char": "u1", "int8": "i1", "uint8": "u1", "int16": "<i2",
    "uint16": "<u2", "int32": "<i4", "uint32": "<u4", "int64": "<i8", "uint64": "<u8",
    "float32": "<f4", "float64": "<f8",
}  # fmt: skip
SEPARATOR = "=" * 80


@dataclass(frozen=True)
class Field:
    """One field of a message type.

    Attributes
    ----------
    name : str
    type : str
        A primitive (``float64``, ``string``, ...) or a full type name ``pkg/msg/Type``.
    array : int or None
        None for a single value, -1 for a sequence (``T[]``, ``T[<=N]``), N >= 0 for a
        fixed-length array ``T[N]``.
    """

    name: str
    type: str
    array: int | None = None

    @property
    def primitive(self) -> bool:
        """Whether the element type is a primitive."""
        return self.type in PRIMITIVES


#: type name -> its fields
Registry = dict[str, tuple[Field, ...]]


def full_name(name: str, package: str) -> str:
    """``pkg/msg/Type`` for ``Type`` (same package), ``pkg/Type`` or ``pkg/msg/Type``.

    A bare ``Header`` is ``std_msgs/msg/Header``, as rosidl resolves it.
    """
    if name == "Header":
        return "std_msgs/msg/Header"
    parts = name.split("/")
    if len(parts) == 1:
        return f"{package}/msg/{name}"
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return name


_FIELD = re.compile(r"^([A-Za-z][\w/]*)(<=\d+)?(\[(<=)?(\d*)\])?\s+([A-Za-z]\w*)(\s*=.*|\s+.*)?$")


def parse_msg(text: str, type_name: str) -> tuple[Field, ...]:
    """The fields of one ``.msg`` text (constants and default values are skipped)."""
    package = type_name.split("/")[0]
    fields = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        m = _FIELD.match(line)
        if m is None:
            raise DataError(
                f"message definition of {type_name}, line {lineno}: cannot parse {raw.strip()!r}"
            )
        base, _bound, arr, bounded, size, name, rest = m.groups()
        if rest is not None and rest.lstrip().startswith("="):
            continue  # a constant
        array = None if arr is None else (-1 if bounded or size == "" else int(size))
        ftype = base if base in PRIMITIVES else full_name(base, package)
        fields.append(Field(name, ftype, array))
    return tuple(fields)


def parse_schema(type_name: str, text: str) -> Registry:
    """Every type of a concatenated ``ros2msg`` schema (module docstring), by full name."""
    root = full_name(type_name, type_name.split("/")[0])
    registry: Registry = {}
    sections = re.split(rf"^{SEPARATOR}\s*$", text, flags=re.MULTILINE)
    registry[root] = parse_msg(sections[0], root)
    for section in sections[1:]:
        body = section.lstrip("\n")
        head, _, rest = body.partition("\n")
        if not head.startswith("MSG: "):
            raise DataError(
                f"schema of {type_name}: a section does not start with 'MSG: pkg/Type'"
            )
        name = full_name(head[5:].strip(), root.split("/")[0])
        registry[name] = parse_msg(rest, name)
    missing = sorted(
        {f.type for fs in registry.values() for f in fs if not f.primitive} - set(registry)
    )
    if missing:
        raise DataError(f"schema of {type_name} lacks the definition of {', '.join(missing)}")
    return registry


# -- installed interfaces ---------------------------------------------------------------
_BUILTIN = {
    "bool",
    "byte",
    "char",
    "float32",
    "float64",
    "int8",
    "uint8",
    "int16",
    "uint16",
    "int32",
    "uint32",
    "int64",
    "uint64",
    "string",
    "wstring",
}


def _share_dirs(extra: Sequence[Path] = ()) -> list[Path]:
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefixes.append(sys.prefix)
    return [Path(d) for d in extra] + [Path(p) / "share" for p in dict.fromkeys(prefixes)]


def _interface_file(type_name: str, suffix: str, extra: Sequence[Path] = ()) -> Path:
    pkg, kind, name = _split(type_name)
    for share in _share_dirs(extra):
        f = share / pkg / kind / f"{name}{suffix}"
        if f.is_file():
            return f
    raise MrIdentError(
        f"interface file {pkg}/{kind}/{name}{suffix} not found under AMENT_PREFIX_PATH "
        f"or {sys.prefix}/share"
    )


def _split(type_name: str) -> tuple[str, str, str]:
    parts = type_name.split("/")
    if len(parts) == 2:
        return parts[0], "msg", parts[1]
    if len(parts) == 3:
        return parts[0], parts[1], parts[2]
    raise MrIdentError(f"type name must be pkg/msg/Type, got {type_name!r}")


def message_definition(type_name: str, extra: Sequence[Path] = ()) -> str:
    """The full concatenated ``ros2msg`` definition of ``type_name`` (rosbag2's form).

    From the ``.msg`` files under ``extra`` (directories laid out as ``pkg/msg/Type.msg``,
    searched first), AMENT_PREFIX_PATH and this environment's ``share``.
    """
    pkg = _split(type_name)[0]

    def deps(pkg: str, text: str) -> list[str]:
        out = []
        for line in text.splitlines():
            line = line.split("#", 1)[0].strip()
            if not line or re.match(r"^\S+\s+\w+\s*=", line):  # blank, comment or constant
                continue
            base = re.sub(r"(<=\d+)?(\[[^\]]*\])?$", "", line.split()[0])
            if base not in _BUILTIN:
                out.append(base if "/" in base else f"{pkg}/{base}")
        return out

    texts: dict[str, str] = {}  # "pkg/Type" -> its .msg text, in first-visit order

    def visit(p: str, text: str) -> None:
        for d in deps(p, text):
            dp, _, dn = _split(d)
            key = f"{dp}/{dn}"
            if key not in texts:
                texts[key] = _interface_file(f"{dp}/msg/{dn}", ".msg", extra).read_text()
                visit(dp, texts[key])

    main = _interface_file(type_name, ".msg", extra).read_text()
    visit(pkg, main)
    parts = [main.rstrip("\n")] + [
        f"{SEPARATOR}\nMSG: {key}\n" + text.rstrip("\n") for key, text in texts.items()
    ]
    return "\n".join(parts) + "\n"


def type_hash(type_name: str) -> str:
    """The RIHS01 type hash of ``type_name`` from its installed ``.json`` description."""
    doc = json.loads(_interface_file(type_name, ".json").read_text())
    for entry in doc.get("type_hashes", []):
        if entry.get("type_name") == "/".join(_split(type_name)):
            return str(entry["hash_string"])
    raise MrIdentError(f"no type hash for {type_name} in its .json description")


def installed_schema(type_name: str) -> str:
    """The concatenated ``ros2msg`` text of an installed type (from its ``.msg`` files)."""
    return message_definition(type_name)


def find_definition(type_name: str, extra: Sequence[Path] = ()) -> str:
    """:func:`message_definition`, or "" when a type it needs is found nowhere."""
    try:
        return message_definition(type_name, extra)
    except (MrIdentError, OSError):
        return ""
