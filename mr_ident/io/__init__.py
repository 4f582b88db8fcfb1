# SPDX-License-Identifier: Apache-2.0
"""I/O: data files (CSV, NPZ), model files, node/replay configuration, recordings and bags.

Above :mod:`mr_ident.numerics`, beneath the live layer. No ROS import: recordings are
read and written with the ``mcap`` packages.
"""
