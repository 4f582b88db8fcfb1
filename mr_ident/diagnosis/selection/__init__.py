# SPDX-License-Identifier: Apache-2.0
"""Selection: causes fitted to the criterion, chosen together, and their equivalents.

:mod:`~mr_ident.diagnosis.selection.fitting` (one cause alone, several jointly, their
std), :mod:`~mr_ident.diagnosis.selection.forward` (forward selection with joint re-fits)
and :mod:`~mr_ident.diagnosis.selection.equivalence` (other causes the data cannot tell
apart from a chosen one). Nothing is imported here: import the modules.
"""
