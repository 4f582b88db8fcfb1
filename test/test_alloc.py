# SPDX-License-Identifier: Apache-2.0
"""The programs' allocator setting: harmless to call, idempotent, reports whether it applied."""

import importlib
import sys

alloc = importlib.import_module("mr_ident.allocator")


def test_keep_freed_memory_applies_on_glibc_and_is_idempotent():
    first, second = alloc.keep_freed_memory(), alloc.keep_freed_memory()
    assert first is second
    if sys.platform.startswith("linux"):
        assert first is True  # this machine: glibc
