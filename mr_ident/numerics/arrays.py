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
