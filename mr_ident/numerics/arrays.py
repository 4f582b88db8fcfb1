# SPDX-License-Identifier: Apache-2.0
"""Array type aliases used across the package (all NumPy arrays, dtype stated)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
IntArray = NDArray[np.int64]
IndexArray = NDArray[np.intp]
BoolArray = NDArray[np.bool_]
#: An array whose dtype depends on the input (real or complex, as given).
AnyArray = NDArray[Any]


def readonly(a: object, dtype: type, *, copy: bool = False) -> AnyArray:
    """``a`` as an array of ``dtype`` that cannot be written through.

    A read-only view unless a conversion or ``copy`` makes a new array: how frozen results
    hold arrays.
    """
    out: AnyArray = (
        np.array(a, dtype=dtype, copy=True) if copy else np.asarray(a, dtype=dtype).view()
    )
    out.setflags(write=False)
    return out


def frozen(a: object, dtype: type) -> AnyArray:
    """``a`` as a read-only array of ``dtype`` that no one else writes through.

    An array of that dtype that is read-only down to the array owning its memory is taken
    as it is (a view: its owner has given up writing it); anything else is copied (a
    read-only view of a writeable array too: its owner may still write). How
    :class:`~mr_ident.numerics.results.FRF` holds its arrays without copying what an
    estimator hands over read-only.
    """
    if isinstance(a, np.ndarray) and a.dtype == dtype:
        base: object = a
        while isinstance(base, np.ndarray) and not base.flags.writeable:
            base = base.base
        if base is None:  # every array up to the owner is read-only
            return readonly(a, dtype)
    return readonly(a, dtype, copy=True)
