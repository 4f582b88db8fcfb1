# SPDX-License-Identifier: Apache-2.0
"""The application layer: a request (a recording, its sources, options) in, a result out.

One path for the command line, ``mr-ident batch`` and replay (the node's turn comes):
:mod:`.requests` (what is asked, frozen), :mod:`.reading` (a recording as loop data, the
rates settled), :mod:`.identify` (P_h and the PFG, or the BLA of periodic data:
:mod:`.periodic`), :mod:`.diagnose`, :mod:`.replay`. Nothing here prints: what the user
should know comes back as :class:`~.requests.Notice` (and through a ``notify`` callback as
it happens). Like the rooms beneath, this ``__init__`` imports nothing (lean start-up).
"""
