# SPDX-License-Identifier: Apache-2.0
"""The live view: a page on localhost that plots the node's estimate as it arrives.

:mod:`.state` holds the latest estimate and stream health (no ROS, no HTTP); :mod:`.server`
serves the page, ``/estimate.json`` and server-sent events; the ROS listener that feeds the
state is :mod:`mr_ident.ros.view`, the replay of a bag :func:`mr_ident.live.replay.bag_estimates`.
"""
