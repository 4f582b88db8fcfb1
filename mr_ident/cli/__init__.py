# SPDX-License-Identifier: Apache-2.0
"""Command line: ``mr-ident simulate | identify | fit | paper | diagnose | replay | demo``.

``record``, ``replay --publish``, ``excite --publish`` and ``demo`` need rclpy (imported
only for them).

User errors print ``error: ...`` to stderr and exit with status 2, never a traceback.
"""

from __future__ import annotations

import sys
import warnings
from collections.abc import Sequence

from ..allocator import keep_freed_memory
from ..errors import MrIdentError
from .common import told
from .parser import EXIT_USAGE, build_parser

__all__ = ["build_parser", "main"]


def _ros_program(argv: Sequence[str]) -> bool:
    """Whether the command line runs a ROS program (record, demo, replay/excite --publish)."""
    command = next((a for a in argv if not a.startswith("-")), None)
    return command in ("record", "demo") or (
        command in ("replay", "excite") and "--publish" in argv
    )


# the arguments that name a file a command writes (any command that has them)
OUTPUTS = ("out", "plot", "json", "report", "out_model")
# the image formats a --plot may name (matplotlib's, without its raw buffers)
YAML = (".yaml", ".yml")
PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".svgz", ".jpg", ".jpeg", ".tif", ".tiff", ".webp")


def check_outputs(args: object) -> None:
    """Refuse bad outputs before anything is computed.

    An output whose folder does not exist, or a plot whose format is unknown: a command
    that fails writes none of its outputs.
    """
    from pathlib import Path

    from ..errors import ConfigError
    from ..io.atomic import missing_folder

    for name in OUTPUTS:
        path = getattr(args, name, None)
        if isinstance(path, Path) and (missing := missing_folder(path)) is not None:
            raise missing
    command = getattr(args, "command", None)
    for name in ("out", "out_model"):
        path = getattr(args, name, None)
        model_file = (command, name) in (("fit", "out"), ("diagnose", "out_model"))
        if model_file and isinstance(path, Path) and path.suffix.lower() not in YAML:
            option = "--" + name.replace("_", "-")
            raise ConfigError(f"{option} must be a model file (.yaml or .yml), got {str(path)!r}")
    plot = getattr(args, "plot", None)
    if isinstance(plot, Path) and plot.suffix.lower() not in PLOT_SUFFIXES:
        raise ConfigError(
            f"--plot must be an image file ({', '.join(PLOT_SUFFIXES)}), got {str(plot)!r}"
        )


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``mr-ident``; user errors print ``error: ...`` and return 2."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if _ros_program(argv):
        from ..ros.program import handle_signals

        handle_signals()  # before anything slow: a signal from now on stops cleanly
    args = build_parser().parse_args(argv)
    keep_freed_memory()
    from . import diagnose_cmd, excite, fit_cmd, live, offline

    commands = {
        "simulate": offline.cmd_simulate,
        "identify": offline.cmd_identify,
        "paper": offline.cmd_paper,
        "batch": offline.cmd_batch,
        "replay": live.cmd_replay,
        "record": live.cmd_record,
        "view": live.cmd_view,
        "demo": live.cmd_demo,
        "diagnose": diagnose_cmd.cmd_diagnose,
        "excite": excite.cmd_excite,
        "fit": fit_cmd.cmd_fit,
    }
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            warnings.simplefilter("ignore", DeprecationWarning)  # third-party import noise (lark)
            check_outputs(args)
            return commands[args.command](args)
    except MrIdentError as err:
        print(f"error: {told(err)}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as err:
        print(f"error: {err.filename or ''}: {err.strerror or err}", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
