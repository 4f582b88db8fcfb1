# SPDX-License-Identifier: Apache-2.0
"""Names offered on the command line, importable without numpy or scipy.

The parser needs the method names to build ``--method``; importing the methods themselves
would load numpy and the numerics before ``--help`` could answer. :data:`METHOD_NAMES` is checked
against :data:`~mr_ident.numerics.lifted.methods.METHODS` by the tests.
"""

#: The identification methods, in the README's order.
METHOD_NAMES: tuple[str, ...] = ("freq-lifted", "time-lifted", "lpm", "structured", "etfe")

#: The local models of the LPM methods' windows, the default first
#: (:mod:`mr_ident.numerics.local.fit`).
LOCAL_MODELS: tuple[str, ...] = ("polynomial", "rational")
#: The message forms ``mr-ident excite --publish`` streams (``--as``; README, "Excitation
#: design"): the block contract, a JointState position, a forward_command_controller command.
EXCITATION_FORMS: tuple[str, ...] = ("block", "jointstate", "float64multiarray", "multidofcommand")
