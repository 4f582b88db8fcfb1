# SPDX-License-Identifier: Apache-2.0
"""Frozen results: they hold their arrays read-only, and no caller writes them afterwards."""

import numpy as np
import pytest

from mr_ident.numerics.results import FRF


def test_a_result_copies_writeable_arrays_and_keeps_read_only_ones_uncopied():
    f, P, s = np.arange(1.0, 4.0), np.ones((3, 1, 1), complex), np.zeros((3, 1, 1))
    given = FRF(f, P, s, "m")
    P[0] = 5.0  # the caller writes its array afterwards: the result does not change
    assert given.response[0, 0, 0] == 1.0 and not given.response.flags.writeable
    for a in (f, P, s):
        a.flags.writeable = False  # handed over
    handed = FRF(f, P, s, "m")
    assert np.shares_memory(handed.response, P) and np.shares_memory(handed.frequency, f)
    with pytest.raises(ValueError):
        handed.response[0, 0, 0] = 2.0
    owner = np.ones((3, 1, 1), complex)
    view = owner[:]
    view.flags.writeable = False  # read-only, but its owner may still write: copied
    assert not np.shares_memory(FRF(f, view, s, "m").response, owner)
