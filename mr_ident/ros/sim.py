# SPDX-License-Identifier: Apache-2.0
"""``mr-ident-sim``: the simulated loop of a model file, published per the topic contract.

Publishes blocks of r_h, u_h, y_h on ``reference``, ``input``, ``output``
(remappable with ``--ros-args -r``), in real time or ``--rate`` times faster,
with white-noise or multisine excitation; the state of the simulation carries
over from block to block (:class:`~mr_ident.simulate.LoopStream`).

``--reference-topic TOPIC``: the loop takes r from TOPIC instead (the block contract,
e.g. ``mr-ident excite --publish TOPIC``), as a machine takes a command: each block's
samples are simulated once, when they arrive, and u and y published at the same indices
on ``input`` and ``output`` (r is TOPIC's: the sim does not publish it again). The loop
starts at the first index that is a multiple of F; indices that never came are run
with r = 0 (the machine ran on without excitation), repeated ones are ignored.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from typing import Any

from ..errors import MrIdentError
from ..io.blocks import STREAMS
from ..io.excitefile import read_excitation
from ..io.modelfile import load_model
from ..numerics.arrays import FloatArray
from ..numerics.excitation.sources import Follower, SimSource
from ..numerics.systems.model import Model
from .program import Stop, handle_signals, ros_context, spin_until_stopped, wants_help


def excitation_signal(path: str, model: Model) -> FloatArray:
    """Every realization of an excitation file one after another, shape (M·P·N, n_r).

    MrIdentError when the file's rate or inputs are not the model's.
    """
    r, fs, _ = read_excitation(path)
    if fs != model.fs_high:
        raise MrIdentError(f"{path} is at fs_high = {fs:g} Hz, the model at {model.fs_high:g} Hz")
    if r.shape[2] != model.n_r:
        raise MrIdentError(f"{path} has {r.shape[2]} input(s), the model's r {model.n_r}")
    return r.reshape(-1, r.shape[2])


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``mr-ident-sim``."""
    p = argparse.ArgumentParser(prog="mr-ident-sim", description=__doc__.splitlines()[0])
    p.add_argument("model", help="model file (YAML), e.g. config/paper_example.yaml")
    p.add_argument(
        "--rate", type=float, default=1.0, help="times faster than real time (default 1)"
    )
    p.add_argument(
        "--block", type=int, default=1000, help="samples per block message (default 1000)"
    )
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        help="seconds of simulated time (default: until Ctrl-C)",
    )
    p.add_argument(
        "--excitation",
        default="white",
        help="white, multisine, or an excitation file of mr-ident excite (FILE.npz: every "
        "realization in turn, looped)",
    )
    p.add_argument(
        "--period", type=float, default=10.0, help="multisine period in seconds (default 10)"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--reference-topic",
        metavar="TOPIC",
        help="take r from TOPIC (block contract, e.g. mr-ident excite --publish TOPIC) and "
        "publish u and y at its indices, as they arrive",
    )
    p.add_argument(
        "--wait",
        type=float,
        default=5.0,
        help="wait up to this many seconds for subscribers on every topic (default 5)",
    )
    p.add_argument(
        "--subscribers",
        type=int,
        default=1,
        help="subscribers to wait for on every topic, e.g. 2 for a node and a recorder "
        "(default 1)",
    )
    return p


def run(
    node: object,
    source: SimSource,
    *,
    rate: float,
    duration: float | None,
    wait: float,
    subscribers: int = 1,
    stop: Stop | None = None,
) -> int:
    """Publish blocks from ``source`` on ``node``'s three publishers.

    Once ``subscribers`` match every topic (or ``wait`` s have passed), until ``duration``
    or a stop; returns blocks sent per topic.
    """
    from rclpy.duration import Duration
    from std_msgs.msg import Float64MultiArray

    from .messages import BLOCK_QOS, block_msg

    stop = stop if stop is not None else Stop()
    pubs = [node.create_publisher(Float64MultiArray, t, BLOCK_QOS) for t in STREAMS]  # type: ignore[attr-defined]
    deadline = time.monotonic() + wait
    while (
        time.monotonic() < deadline
        and not stop.requested
        and any(p.get_subscription_count() < subscribers for p in pubs)
    ):
        stop.wait(0.02)
    if wait > 0:
        stop.wait(min(wait, 0.5))  # matching is not symmetric: let the subscribers match us too
    fs = source.model.fs_high
    total = None if duration is None else int(round(duration * fs))
    t0 = time.monotonic()
    sent = 0
    start = source.next_index
    while not stop.requested and (total is None or source.next_index - start < total):
        first, r, u, y = source.next()
        due = t0 + (first + source.block - start) / fs / rate
        while (delay := due - time.monotonic()) > 0 and not stop.requested:
            stop.wait(min(delay, 0.1))
        if stop.requested:
            break
        for pub, x in zip(pubs, (r, u, y), strict=True):
            pub.publish(block_msg(first, x))
        sent += 1
    for pub in pubs:  # reliable delivery: do not exit before the readers have it
        pub.wait_for_all_acked(Duration(seconds=1 if stop.requested else 5))
    return sent


def run_driven(
    node: object,
    model: Model,
    topic: str,
    *,
    duration: float | None,
    seed: int = 0,
    stop: Stop | None = None,
) -> int:
    """Simulate the loop on the reference blocks of ``topic`` (see the module).

    Until ``duration`` s of loop time were simulated or a stop; returns blocks sent per
    topic.
    """
    from rclpy.duration import Duration
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Float64MultiArray

    from ..io.blocks import BlockError
    from .messages import BLOCK_QOS, block_msg, decode_raw

    stop = stop if stop is not None else Stop()
    follower = Follower(model, seed)
    n: Any = node
    pubs = [n.create_publisher(Float64MultiArray, t, BLOCK_QOS) for t in STREAMS[1:]]
    total = None if duration is None else int(round(duration * model.fs_high))
    sent = 0

    def on_block(raw: bytes) -> None:
        nonlocal sent
        block = decode_raw(raw)
        if isinstance(block, BlockError):
            n.get_logger().warning(f"reference block dropped: {block}")
            return
        ready = follower.offer(block.first, block.samples)
        if ready is None:
            return
        first, u, y = ready
        for pub, x in zip(pubs, (u, y), strict=True):
            pub.publish(block_msg(first, x))
        sent += 1
        if total is not None and follower.simulated >= total:
            stop.request()

    n.create_subscription(Float64MultiArray, topic, on_block, BLOCK_QOS, raw=True)
    executor = SingleThreadedExecutor(context=n.context)
    executor.add_node(n)
    try:
        spin_until_stopped(executor, n, stop)
    finally:
        executor.remove_node(n)
    for pub in pubs:
        pub.wait_for_all_acked(Duration(seconds=1 if stop.signal is not None else 5))
    return sent


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``mr-ident-sim``.

    SIGINT/SIGTERM stop it through one path (:mod:`mr_ident.ros.program`) with exit 0.
    """
    args_all = list(sys.argv if argv is None else argv)
    if wants_help(args_all[1:]):  # the usage needs no ROS (nor rclpy installed)
        build_parser().parse_args(["--help"])
    stop = handle_signals()
    from rclpy.utilities import remove_ros_args

    args = build_parser().parse_args(remove_ros_args(args_all)[1:])
    try:
        model = load_model(args.model)
        if args.rate <= 0 or not math.isfinite(args.rate):
            raise MrIdentError(f"--rate must be a positive number, got {args.rate}")
        if args.subscribers < 0:
            raise MrIdentError(f"--subscribers must be >= 0, got {args.subscribers}")
        if args.block < 1:
            raise MrIdentError(f"--block must be >= 1 sample, got {args.block}")
        kind, signal = args.excitation, None
        if kind not in ("white", "multisine"):
            kind, signal = "signal", excitation_signal(args.excitation, model)
        source = SimSource(
            model,
            block=args.block,
            excitation=kind,
            seed=args.seed,
            period_s=args.period,
            signal=signal,
        )
    except MrIdentError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    with ros_context(args_all) as rclpy:
        node = rclpy.create_node("mr_ident_sim")
        try:
            if args.reference_topic:
                sent = run_driven(
                    node,
                    model,
                    args.reference_topic,
                    duration=args.duration,
                    seed=args.seed,
                    stop=stop,
                )
                node.get_logger().info(
                    f"published {sent} blocks of u and y for the reference on "
                    f"{args.reference_topic}"
                )
                return 0
            sent = run(
                node,
                source,
                rate=args.rate,
                duration=args.duration,
                wait=args.wait,
                subscribers=args.subscribers,
                stop=stop,
            )
            node.get_logger().info(f"published {sent} blocks of {args.block} samples per topic")
        finally:
            node.destroy_node()
    return 0


if __name__ == "__main__":
    sys.exit(main())
