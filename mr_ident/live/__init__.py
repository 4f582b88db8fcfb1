# SPDX-License-Identifier: Apache-2.0
"""Live: from decoded messages to estimates, the same for the node and for replay.

:mod:`~mr_ident.live.align` (the aligned window), :mod:`~mr_ident.live.ingest` (the one
path every decoded item takes into it), :mod:`~mr_ident.live.estimate` (one window, one
estimate) and :mod:`~mr_ident.live.replay` (a recording through those steps). Above
numerics and I/O; no ROS import.
"""
