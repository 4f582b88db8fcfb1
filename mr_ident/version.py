# SPDX-License-Identifier: Apache-2.0
"""The package version (one place: setup.py reads it too)."""

__version__ = "0.1.0"
