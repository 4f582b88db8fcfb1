# SPDX-License-Identifier: Apache-2.0
"""A configuration error of the node reaches its console, not only /diagnostics: a source
that cannot work is logged once as an error (ros/sources.SourceSubscriber.error)."""

from __future__ import annotations

import pytest

pytest.importorskip("rclpy")

from mr_ident.ros.sources import SourceSubscriber  # noqa: E402


class _Logger:
    def __init__(self) -> None:
        self.errors: list[str] = []

    def error(self, text: str) -> None:
        self.errors.append(text)


class _Node:
    def __init__(self) -> None:
        self.logger = _Logger()

    def get_logger(self) -> _Logger:
        return self.logger

    def resolve_topic_name(self, topic: str) -> str:
        return topic if topic.startswith("/") else "/" + topic


def test_a_source_that_cannot_work_is_told_in_the_console_once():
    node = _Node()
    sub = SourceSubscriber(node, {"y": ("/joint_states.positionx",)}, lambda s: None)  # type: ignore[arg-type,return-value]
    bad = "source /joint_states.positionx: no field positionx in sensor_msgs/msg/JointState"
    sub.error = bad
    sub.error = bad  # every batch that fails sets it again
    assert node.logger.errors == [bad] and sub.error == bad
    sub.error = ""
    assert sub.error == "" and node.logger.errors == [bad]


def test_stamps_that_contradict_fs_high_are_told_in_the_console_once():
    from types import SimpleNamespace

    import numpy as np

    node = _Node()
    sub = SourceSubscriber(node, {}, lambda s: None, fs_high=1000.0)  # type: ignore[arg-type,return-value]
    spec = SimpleNamespace(text="/joint_states.position[0]", hold=False)
    sub.sources = SimpleNamespace(all=[(2, 0, SimpleNamespace(spec=spec))])  # type: ignore[assignment]
    sub._stamps = [[np.arange(200) * 2_000_000]]  # 500 Hz stamps, ns
    first, again = sub.rate_problem(), sub.rate_problem()
    assert first == again and "the stamps say 500 Hz, fs_high is 1000 Hz" in first
    assert node.logger.errors == [first]
