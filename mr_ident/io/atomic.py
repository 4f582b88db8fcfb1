# SPDX-License-Identifier: Apache-2.0
"""Writing a file whole or not at all.

Through a temporary file in the same directory and a rename, so that a failed write (an error, a
full disk, a signal) leaves nothing.
"""

from __future__ import annotations

import errno
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any


def missing_folder(path: str | Path) -> OSError | None:
    """The error of writing ``path`` when its folder does not exist, else None.

    One message everywhere, naming the user's path: the commands check their outputs with
    it before computing anything, and :func:`atomic_write` raises it too.
    """
    folder = Path(path).parent
    if folder.is_dir():
        return None
    return FileNotFoundError(
        errno.ENOENT, f"cannot write it: the folder {str(folder)!r} does not exist", str(path)
    )


def atomic_write(path: str | Path, write: Callable[[Any], Any], binary: bool) -> None:
    """Call ``write(fh)`` on a temporary file beside ``path``.

    Then rename it to ``path`` (usual file mode); on any failure the temporary file is
    removed and nothing is left. A folder that does not exist is an error naming ``path``
    (:func:`missing_folder`), never the temporary file.
    """
    path = Path(path)
    missing = missing_folder(path)
    if missing is not None:
        raise missing
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
