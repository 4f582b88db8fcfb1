# SPDX-License-Identifier: Apache-2.0
"""The criterion: the model on the data, the per-bin evidence, the noise, the objective.

:mod:`~mr_ident.diagnosis.criterion.prediction` (the model simulated on the data),
:mod:`~mr_ident.diagnosis.criterion.evidence` (the model against the identified FRFs, bin
by bin), :mod:`~mr_ident.diagnosis.criterion.noise` (the noise spectrum from the data) and
:mod:`~mr_ident.diagnosis.criterion.objective` (whitened residuals and the BIC every cause
is fitted and ranked by). Nothing is imported here: import the modules.
"""
