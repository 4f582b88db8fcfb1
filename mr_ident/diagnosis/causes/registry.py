# SPDX-License-Identifier: Apache-2.0
"""The cause vocabulary, by name (:data:`CAUSES`).

A new cause is one more class and one more entry here.
"""

from __future__ import annotations

from ...errors import ConfigError
from ...numerics.systems.model import Model
from .cause import Cause, Choice
from .loop_causes import LOOP_CAUSES
from .plant_causes import PLANT_CAUSES

#: The cause vocabulary, by name, in the order of the README table.
CAUSES: dict[str, Cause] = {c.name: c for c in (*PLANT_CAUSES, *LOOP_CAUSES)}


def check_cause(name: str) -> Cause:
    """The registered cause ``name``.

    Raises
    ------
    ConfigError
        Not a cause name.
    """
    if name not in CAUSES:
        raise ConfigError(f"cause must be one of {', '.join(CAUSES)}; got {name!r}")
    return CAUSES[name]


def build(nominal: Model, choices: list[Choice]) -> Model:
    """``nominal`` extended by every choice, in order."""
    model = nominal
    for c in choices:
        model = CAUSES[c.cause].apply(model, c)
    return model
