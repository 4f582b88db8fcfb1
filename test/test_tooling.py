# SPDX-License-Identifier: Apache-2.0
"""The files the ROS tools read: the Foxglove layout names what the node publishes."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_foxglove_layout_reads_the_estimate_and_the_summary():
    """Every plotted path is a field of ~/summary or of the layout's own user script, whose
    input is ~/estimate and which reads only fields the Estimate message has."""
    msg = pytest.importorskip("mr_ident_msgs.msg")
    if not hasattr(msg, "Estimate"):  # the source folder, seen from the repository's root
        pytest.skip("mr_ident_msgs is not built (make venv builds it)")
    layout = json.loads((ROOT / "config" / "foxglove_layout.json").read_text())
    (script,) = layout["userNodes"].values()
    code = script["sourceCode"]
    assert 'inputs = ["/mr_ident/estimate"]' in code
    output = re.search(r'output = "([^"]+)"', code).group(1)
    produced = set(re.findall(r"^\s+(\w+): number\[\];", code, re.M))
    read = set(re.findall(r"\bm\.(\w+)", code))
    assert read <= set(msg.Estimate.get_fields_and_field_types()), read
    summary = set(msg.Summary.get_fields_and_field_types())
    paths = [
        p["value"]
        for cfg in layout["configById"].values()
        for p in [*cfg.get("paths", []), cfg.get("xAxisPath", {"value": f"{output}.pfg[:]"})]
    ]
    assert paths
    for path in paths:
        topic, field = re.match(r"(/[\w/]+)\.(\w+)", path).groups()
        assert (topic == output and field in produced) or (
            topic == "/mr_ident/summary" and field in summary
        ), path
