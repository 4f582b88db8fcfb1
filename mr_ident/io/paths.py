# SPDX-License-Identifier: Apache-2.0
"""Signal sources: a topic and a field path, in Foxglove's message-path syntax.

Grammar (a subset of Foxglove's message paths, one extension, one modifier)::

    source  := topic path? modifier?
    topic   := "/"? name ("/" name)*                     (ROS topic characters; relative:
                                                   the node resolves it in its namespace
                                                   with its remaps, ``~/x`` under its name)
    path    := step*
    step    := "." field                          a field of a message
             | "[" integer "]"                    an element of an array (< 0: from the end)
             | "[:]" "{" field "==" literal "}"   the element of an array of messages whose
                                                  field equals the literal (the first)
             | "{" field "==" literal "}"         extension: the element of a primitive array
                                                  at the index where the parent's sibling
                                                  array ``field`` holds the literal
                                                  (/joint_states.position{name=="j1"})
    literal := '"' characters '"' | number
    modifier:= ".@hold"                                  a low-rate value held over F samples

Examples: ``/joint_states.position{name=="j1"}``, ``/joint_states.effort[0]``,
``/pid_controller/controller_state.dof_states[:]{name=="j1"}.output``, ``/r.data``,
``/controller_manager/introspection_data{name=="state_interface.j1/position"}`` (the
introspection topics, see :mod:`mr_ident.io.sources`) and a bare topic (the block
contract). :func:`parse_source` parses one; a mistake is a :class:`~mr_ident.errors.ConfigError`
that points at its position.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from ..errors import ConfigError

MODIFIERS = ("hold",)


@dataclass(frozen=True)
class Step:
    """One step of a path.

    ``kind`` is "field" (``name``), "index" (``index``), "match" (``[:]{key==value}``) or
    "sibling" (``{key==value}`` on a primitive array).
    """

    kind: str
    name: str = ""
    index: int = 0
    key: str = ""
    value: str | float = ""


@dataclass(frozen=True)
class SourceSpec:
    """A parsed source: ``topic``, its ``steps`` and modifiers; ``text`` as written."""

    text: str
    topic: str
    steps: tuple[Step, ...]
    hold: bool = False

    @property
    def block_contract(self) -> bool:
        """A bare topic: its messages follow the block contract."""
        return not self.steps

    def path_text(self) -> str:
        """The path part as written (after the topic)."""
        return self.text[len(self.topic) :]


def _error(text: str, pos: int, what: str) -> ConfigError:
    return ConfigError(f"source {text!r}: {what} at position {pos + 1}\n  {text}\n  {' ' * pos}^")


_TOPIC = re.compile(r"/?[A-Za-z_~][\w~]*(/[A-Za-z_][\w]*)*")
_NAME = re.compile(r"[A-Za-z_]\w*")
_INT = re.compile(r"-?\d+")
_NUMBER = re.compile(r"-?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def parse_source(text: str) -> SourceSpec:
    """Parse one source spec (module docstring).

    Raises
    ------
    ConfigError
        Naming the spec and pointing at the position of the mistake.

    Examples
    --------
    >>> s = parse_source('/joint_states.position{name=="j1"}')
    >>> s.topic, [st.kind for st in s.steps]
    ('/joint_states', ['field', 'sibling'])
    """
    if not isinstance(text, str) or not text:
        raise ConfigError(f"a source must be a non-empty string, got {text!r}")
    m = _TOPIC.match(text)
    if m is None:
        raise _error(text, 0, "expected a topic name (/robot/js, or relative: js, ~/js)")
    topic = m.group(0)
    pos = m.end()
    # A topic name may contain '/' segments, a path never does: the topic ends at the first
    # '.', '[' or '{'.
    steps: list[Step] = []
    hold = False
    while pos < len(text):
        c = text[pos]
        if text.startswith(".@", pos):
            pos = _modifier(text, pos)
            hold = True
        elif c == ".":
            name = _NAME.match(text, pos + 1)
            if name is None:
                raise _error(text, pos + 1, "expected a field name after '.'")
            steps.append(Step("field", name=name.group(0)))
            pos = name.end()
        elif c == "[":
            step, pos = _bracket(text, pos)
            steps.append(step)
        elif c == "{":
            if not steps or steps[-1].kind != "field":
                if steps:
                    raise _error(text, pos, "a {field==value} filter must follow a field (or [:])")
            key, value, pos = _filter(text, pos)
            steps.append(Step("sibling", key=key, value=value))
        else:
            raise _error(text, pos, f"unexpected {c!r}: expected '.', '[' or '{{'")
    return SourceSpec(text, topic, tuple(steps), hold)


def _modifier(text: str, pos: int) -> int:
    """Parse ``.@hold`` at ``pos`` (the '.'); it must end the source: return its end."""
    mod = _NAME.match(text, pos + 2)
    if mod is None or mod.group(0) not in MODIFIERS:
        raise _error(text, pos + 2, f"unknown modifier (known: {', '.join(MODIFIERS)})")
    if mod.end() != len(text):
        raise _error(text, mod.end(), "a modifier must end the source")
    return mod.end()


def _bracket(text: str, pos: int) -> tuple[Step, int]:
    """Parse ``[:]{key==value}`` or ``[i]`` at ``pos`` (the '['): the step, the next position."""
    if text.startswith("[:]", pos):
        pos += 3
        if not text.startswith("{", pos):
            raise _error(text, pos, 'expected a filter {field=="value"} after [:]')
        key, value, pos = _filter(text, pos)
        return Step("match", key=key, value=value), pos
    num = _INT.match(text, pos + 1)
    if num is None:
        raise _error(text, pos + 1, "expected an integer index or ':'")
    end = num.end()
    if not text.startswith("]", end):
        raise _error(text, end, "expected ']'")
    return Step("index", index=int(num.group(0))), end + 1


def _filter(text: str, pos: int) -> tuple[str, str | float, int]:
    """Parse ``{key==literal}`` at ``pos`` (the '{'); return key, value and the next position."""
    key = _NAME.match(text, pos + 1)
    if key is None:
        raise _error(text, pos + 1, "expected a field name in the filter")
    p = key.end()
    if not text.startswith("==", p):
        raise _error(text, p, "expected '==' in the filter")
    p += 2
    value: str | float
    if text.startswith('"', p):
        close = text.find('"', p + 1)
        if close < 0:
            raise _error(text, p, "unterminated string")
        value, p = text[p + 1 : close], close + 1
    else:
        num = _NUMBER.match(text, p)
        if num is None:
            raise _error(text, p, 'expected a "string" or a number')
        value, p = float(num.group(0)), num.end()
    if not text.startswith("}", p):
        raise _error(text, p, "expected '}' to close the filter")
    return key.group(0), value, p + 1


def parse_sources(texts: list[str] | tuple[str, ...], signal: str) -> tuple[SourceSpec, ...]:
    """Parse the sources of one signal (r, u or y: several for MIMO, one channel each)."""
    if not texts:
        raise ConfigError(f"{signal}: at least one source is needed")
    return tuple(parse_source(t) for t in texts)
