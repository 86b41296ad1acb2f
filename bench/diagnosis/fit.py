"""Weighted least squares of effect parameters (scipy.optimize.least_squares, bounded).

Plain functions, arrays in and out: :func:`fit_effects` returns a
:class:`FitResult` with the parameters, chi-square, BIC, and standard errors
from the whitened Jacobian at the solution.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.space import ParamSpace


@dataclass
class FitResult:
    """``phi`` fit-space values; ``chi2`` sum of squared whitened residuals of the fitted
    samples; ``n_res`` their count; ``bic`` = chi2 + p ln(n_res); ``stderr`` fit-space
    standard errors (inflated by sqrt(chi2/dof) when above 1); ``cov``; ``success``."""

    space: ParamSpace
    phi: np.ndarray
    chi2: float
    n_res: int
    bic: float
    stderr: np.ndarray
    cov: np.ndarray
    success: bool
    message: str
    nfev: int = 0

    @property
    def dof(self) -> int:
        return max(self.n_res - len(self.phi), 1)

    @property
    def reduced_chi2(self) -> float:
        return self.chi2 / self.dof


def bic(chi2: float, n_params: int, n_res: int) -> float:
    """Bayesian information criterion for Gaussian residuals of known noise."""
    return chi2 + n_params * np.log(max(n_res, 2))


def fd_jacobian(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray, f0: np.ndarray,
                steps: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Forward differences with absolute steps, turned inward at the bounds."""
    J = np.empty((len(f0), len(x)))
    for k in range(len(x)):
        h = steps[k] if x[k] + steps[k] <= hi[k] else -steps[k]
        if x[k] + h < lo[k]:
            h = steps[k]
        xp = x.copy()
        xp[k] += h
        J[:, k] = (fun(xp) - f0) / h
    return J


def fit_effects(space: ParamSpace, rm: ResidualModel, idx: np.ndarray,
                phi0: np.ndarray | None = None, max_nfev: int = 60) -> FitResult:
    """Fit the parameters of ``space`` to the samples ``idx`` (whitened inverse residuals)."""

    def fun(phi: np.ndarray) -> np.ndarray:
        return rm.whitened(space.robot(phi), idx)

    x0 = space.neutral.copy() if phi0 is None else np.clip(phi0, space.lo, space.hi)
    steps = space.scale * 1e-2

    def jac(phi: np.ndarray) -> np.ndarray:
        return fd_jacobian(fun, phi, fun(phi), steps, space.lo, space.hi)

    if len(space) == 0:
        r = fun(x0)
        chi2 = float(r @ r)
        return FitResult(space, x0, chi2, len(r), bic(chi2, 0, len(r)), np.zeros(0),
                         np.zeros((0, 0)), True, "no parameters")
    res = least_squares(fun, x0, jac=jac, bounds=(space.lo, space.hi), x_scale=space.scale,
                        method="trf", max_nfev=max_nfev, xtol=1e-10, ftol=1e-10, gtol=1e-10)
    r = res.fun
    chi2 = float(r @ r)
    n_res = len(r)
    cov, se = standard_errors(res.jac, chi2, n_res, space.scale)
    return FitResult(space, res.x, chi2, n_res, bic(chi2, len(res.x), n_res), se, cov,
                     bool(res.success), str(res.message), int(res.nfev))


def standard_errors(J: np.ndarray, chi2: float, n_res: int,
                    scale: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Covariance and standard errors from the whitened Jacobian (computed in parameter
    units of ``scale``); inflated by the reduced chi-square when the fit leaves more than
    the noise. Directions the data do not constrain get infinite standard errors."""
    p = J.shape[1]
    D = np.ones(p) if scale is None else np.asarray(scale, dtype=float)
    Js = J * D
    JtJ = Js.T @ Js
    w, V = np.linalg.eigh(JtJ)
    top = max(float(w.max()), 1e-300)
    weak = w < 1e-12 * top
    inv_w = np.where(weak, 0.0, 1.0 / np.where(weak, 1.0, w))
    cov_s = (V * inv_w) @ V.T
    red = chi2 / max(n_res - p, 1)
    cov = cov_s * np.outer(D, D) * max(red, 1.0)
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    if weak.any():
        null = (V[:, weak] ** 2).sum(axis=1) > 1e-3
        se = np.where(null, np.inf, se)
    return cov, se
