# SPDX-License-Identifier: Apache-2.0
"""The controller's own equation on one record: the residual ``u - û`` of any model.

See :mod:`.relation` for what the equation is and what it decides.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ...numerics.arrays import FloatArray
from ...numerics.signals import LoopData
from ...numerics.systems.lti import StateSpace
from ...numerics.systems.model import Model
from ...numerics.systems.simulate import StateRecursion
from ..criterion.objective import project_out


class Equation:
    """The controller's equation on one record: residual ``u - û`` of any model.

    From :attr:`start` on (past the longest hold of any candidate: a control delay up to
    2F and a sampling phase up to F - 1 more than the nominal's, so every held output was
    computed within the record). Projected out of it: the controller's free responses
    (its unknown state at the record's start) and a constant per channel of u (a
    feedforward or trim the controller adds, an offset of y through K_l's DC gain; with
    the free responses they span a step's response). Divided by the rms of the logged
    controller output (``r - u``, or ``-u`` with r the setpoint) with the same projected
    out, so a large trim does not dilute it.
    """

    def __init__(self, rec: LoopData, nominal: Model):
        self.u_missing, self.y_missing = np.isnan(rec.u), np.isnan(rec.y)
        self.u = np.where(self.u_missing, 0.0, rec.u)
        self.y = np.where(self.y_missing, 0.0, rec.y)
        # the controller's output as the logged u gives it, and what the controller samples:
        # u = r - u_c and y (r at the plant input), or u = -u_c and y - r (r the setpoint)
        setpoint = nominal.setpoint
        self.logged = -self.u if setpoint else rec.r - self.u
        self.sampled = self.y - rec.r if setpoint else self.y
        self.F = nominal.ratio
        self.M = rec.n_samples // self.F
        hold = nominal.sample_phase + nominal.control_delay
        self.start = self.F * (hold // self.F + 6)
        idx = np.arange(self.start, self.F * self.M)
        self.keep = ~self.u_missing[idx].ravel()  # the equations of a missing u: left out
        out = self.logged[idx].ravel()[self.keep]
        ones: FloatArray = np.tile(np.eye(self.u.shape[1]), (idx.size, 1))
        self._const = ones  # (n * n_u, n_u): a constant per channel
        self.scale = float(np.sqrt(np.mean(project_out(ones[self.keep], out) ** 2))) or 1.0

    @property
    def samples(self) -> int:
        """High-rate samples the residual covers (a missing u's left out)."""
        lost = self.u_missing[self.start : self.F * self.M].any(axis=1)
        return int(self.F * self.M - self.start - lost.sum())

    def holes(self, model: Model) -> FloatArray:
        """The controller's response to a unit sample at each missing y it samples.

        Shape (M, n_u, n_h), one column per missing sampled y (the period's sample at
        ``model``'s phase, per channel), like the free responses.
        """
        lost = self.y_missing[model.sample_phase :: self.F][: self.M]
        where = np.argwhere(lost)
        n_u = self.u.shape[1]
        if not where.size:
            return np.zeros((self.M, n_u, 0))
        K = model.controller_ss()
        pulse = np.zeros((self.M, lost.shape[1]))
        resp = []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for ch in range(lost.shape[1]):
                pulse[:] = 0.0
                pulse[0, ch] = 1.0
                resp.append(StateRecursion(K).run(pulse))  # (M, n_u)
        out = np.zeros((self.M, n_u, where.shape[0]))
        for col, (m, ch) in enumerate(where):
            out[m:, :, col] = resp[ch][: self.M - m]
        return out

    def outputs(self, model: Model) -> tuple[FloatArray, FloatArray]:
        """``model``'s controller on the y it samples: outputs from rest and free responses.

        Shapes (M, n_u) and (M, n_u, nk), one row per low-rate period.
        """
        K = model.controller_ss()
        ys = self.sampled[model.sample_phase :: self.F][: self.M]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a defective controller: the direct recursion
            return StateRecursion(K).run(ys), _free_responses(K, self.M)

    def residual(self, model: Model) -> FloatArray:
        """``(u - û) / scale`` from :attr:`start` on, free responses projected out (flat)."""
        F, M = self.F, self.M
        hold = model.sample_phase + model.control_delay
        uc, free = self.outputs(model)
        idx = np.arange(self.start, F * M)
        i, m = idx % F, idx // F
        j = -((i - hold) // F)  # the output held at sample i is the one of period m - j
        src = m - j
        if src.size and src[0] < 0:  # a hold longer than the candidates' (never in relate)
            return np.full(idx.size * self.u.shape[1], math.inf)
        e = uc[src] - self.logged[idx]
        res = e.ravel()[self.keep] / self.scale
        unknown = np.concatenate([free, self.holes(model)], axis=2)  # state, missing y
        nk = unknown.shape[-1]
        A = np.concatenate([-unknown[src].reshape(idx.size * free.shape[1], nk), self._const], 1)
        return project_out(A[self.keep], res)

    def error(self, model: Model) -> float:
        """The rms of :meth:`residual`: how far ``model``'s controller departs, relatively."""
        with np.errstate(over="ignore", invalid="ignore"):  # an unstable candidate: inf
            res = self.residual(model)
            return float(np.sqrt(np.mean(res**2))) if np.all(np.isfinite(res)) else math.inf


def _free_responses(K: StateSpace, M: int) -> FloatArray:
    """The controller's output from each unit initial state with zero input, (M, n_u, nk)."""
    nk, nu = K.A.shape[0], K.C.shape[0]
    if not nk:
        return np.zeros((M, nu, 0))
    probe = StateSpace(K.A, np.eye(nk), K.C, np.zeros((nu, nk)), K.dt)
    w = np.zeros((M + 1, nk))
    cols = []
    for s in range(nk):
        w[:] = 0.0
        w[0, s] = 1.0
        cols.append(StateRecursion(probe).run(w)[1:])  # x[m] = A^(m-1) e_s, from m = 1
    return np.stack(cols, axis=-1)
