# SPDX-License-Identifier: Apache-2.0
"""Print which BLAS kernels numpy and scipy run here, one line.

OpenBLAS picks its kernels for the CPU at load, or those ``OPENBLAS_CORETYPE`` names;
threadpoolctl reads back what it chose. `.ci/run` runs the numerics part of the suite once
per distinct line among the core types it tests (a wheel built without a core type's own
kernels runs another's: then the two lines are equal).

    .venv/bin/python scripts/blas_kernels.py    # numpy 2.3.5: openblas 0.3.30 Haswell; ...
"""

from __future__ import annotations

import numpy
import scipy
import scipy.linalg  # noqa: F401  (loads scipy's own BLAS)
from threadpoolctl import threadpool_info


def main() -> None:
    libs = "; ".join(
        f"{lib['internal_api']} {lib['version']} {lib.get('architecture', '?')}"
        for lib in threadpool_info()
        if lib["user_api"] == "blas"
    )
    print(f"numpy {numpy.__version__}, scipy {scipy.__version__}: {libs}")


if __name__ == "__main__":
    main()
