# SPDX-License-Identifier: Apache-2.0
"""Systems: LTI systems, their realisations, the loop model and its simulation.

:mod:`~mr_ident.numerics.systems.lti` (transfer-function matrices and state space),
:mod:`~mr_ident.numerics.systems.realize` (realisations that keep their digits),
:mod:`~mr_ident.numerics.systems.model` (the nominal loop, :class:`Model`),
:mod:`~mr_ident.numerics.systems.simulate` (simulation by lifting) and
:mod:`~mr_ident.numerics.systems.window_response` (the loop's y over a window). Nothing is
imported here: import the modules.
"""
