# SPDX-License-Identifier: Apache-2.0
"""Lifecycle requests answered as rclcpp_lifecycle answers them.

rclpy 7.1.6's ``~/change_state`` raises ``RCLError: ... Transition is not registered`` out
of the executor when a request names a transition (by id, as launch's lifecycle event
handlers and lifecycle managers send them) that the current state does not have: the node
dies. rclcpp_lifecycle answers such a request with ``success: false`` and logs why; so does
:func:`answer_every_request`, and the node lives on. A transition the state has goes to
rclpy's own handler, which runs the node's callbacks.
"""

from __future__ import annotations

import functools
import traceback
from collections.abc import Callable
from typing import Any

from lifecycle_msgs.msg import Transition
from rclpy.lifecycle import LifecycleState, TransitionCallbackReturn

#: Transition ids by name (lifecycle_msgs/msg/Transition), for the log.
_NAMES = {
    getattr(Transition, k): k.removeprefix("TRANSITION_").lower()
    for k in dir(Transition)
    if k.startswith("TRANSITION_") and isinstance(getattr(Transition, k), int)
}


def state_label(node: Any) -> str:
    """The node's current lifecycle state (``unconfigured``, ``inactive``, ...)."""
    return str(node._state_machine.current_state[1])


def refusal(node: Any, transition_id: int, label: str) -> str:
    """Why the current state has no such transition ("" when it has): label first, as rcl."""
    available = [(t[0], t[1]) for t in node._state_machine.available_transitions]
    if any((lab == label) if label else (tid == transition_id) for tid, lab in available):
        return ""
    state = state_label(node)
    asked = f"'{label}'" if label else f"{transition_id} ({_NAMES.get(transition_id, '?')})"
    allowed = ", ".join(dict.fromkeys(lab for _, lab in available)) or "none"
    return (
        f"lifecycle transition {asked} refused: the node is {state} "
        f"(transitions from {state}: {allowed})"
    )


def answer_every_request(node: Any) -> None:
    """Make ``node``'s ``~/change_state`` answer every request (see the module docstring)."""
    service = getattr(node, "_service_change_state", None)
    if service is None:  # no communication interface
        return
    handle = service.callback

    def change_state(req: Any, resp: Any) -> Any:
        why = refusal(node, req.transition.id, req.transition.label)
        if why:
            node.get_logger().error(why)
            resp.success = False
            return resp
        return handle(req, resp)

    service.callback = change_state


def logged(transition: Callable[..., Any]) -> Callable[..., Any]:
    """A transition callback whose exception is logged with its traceback (rclpy: ERROR)."""

    @functools.wraps(transition)
    def run(node: Any, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            return transition(node, state)
        except Exception:
            node.get_logger().error(f"{transition.__name__} raised:\n{traceback.format_exc()}")
            return TransitionCallbackReturn.ERROR

    return run
