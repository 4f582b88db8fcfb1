# SPDX-License-Identifier: Apache-2.0
"""Writing a file whole or not at all.

Through a temporary file in the same directory and a rename, so that a failed write (an error, a
full disk, a signal) leaves nothing.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any


def atomic_write(path: str | Path, write: Callable[[Any], Any], binary: bool) -> None:
    """Call ``write(fh)`` on a temporary file beside ``path``.

    Then rename it to ``path`` (usual file mode); on any failure the temporary file is
    removed and nothing is left.
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent or ".")
    try:
        with os.fdopen(fd, "wb" if binary else "w") as fh:
            write(fh)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the usual file mode
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
