"""Test oracle: the former numpy inverses of the engine (LAPACK SVD), as small frozen strategies.

Every strategy maps a Jacobian ``J (..., 6, n)`` and a twist ``xdot (..., 6)`` to joint rates
``qd (..., n)``. Parameters may be scalars or arrays of shape ``(B,)`` matching a leading
batch axis, so one strategy object evaluates a whole GA population at once.

All SVD-based strategies are written as filters of the singular values,
``qd = sum_i f(sigma_i) v_i u_i^T xdot``, and report an *effective damping* per singular
direction, ``lambda_i = sqrt(sigma_i / f_i - sigma_i^2)``: the constant-damping value that
would give the same gain (0 means undamped; for DLS it is the damping itself).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import numpy as np
from oracle.spatial import FloatArray

from engine import inverses as engine_inverses

_TINY = 1e-300


class SVD(NamedTuple):
    """Thin SVD ``J = U diag(s) Vt``: ``U (..., 6, m)``, ``s (..., m)`` descending, ``Vt (..., m, n)``."""

    U: FloatArray
    s: FloatArray
    Vt: FloatArray


# thin_svd keeps its eigen route for a member only if s_{m-1} >= _GRAM_SECOND_SMALLEST s_1 and
# s_m >= _GRAM_SMALLEST s_1 (m = min(r, c)); see its docstring for the error bounds.
_GRAM_SECOND_SMALLEST = 1e-2
_GRAM_SMALLEST = 1e-7


@functools.cache
def _gram_floor(m: int) -> FloatArray:
    """Floors ``(m,)`` of ``s / s_1`` for the eigen route of :func:`thin_svd`."""
    floor = np.zeros(m)
    if m > 1:
        floor[-2] = _GRAM_SECOND_SMALLEST
    floor[-1] = _GRAM_SMALLEST
    floor.setflags(write=False)
    return floor


def thin_svd(J: FloatArray) -> SVD:
    """Thin SVD of ``J (..., r, c)`` for any leading batch shape; ``m = min(r, c)``.

    On stacks of small matrices LAPACK's per-matrix cost dominates, and a symmetric
    eigen-decomposition costs about 60 % of an SVD, so the SVD is built from the
    eigenvectors ``E`` (descending eigenvalues) of the smaller Gram matrix, ``M M^T`` with
    ``M = J`` if ``c >= r``, else ``M = J^T``. The rows of ``W = E^T M`` are ``s_i f_i^T``:
    the singular values are their norms, accurate to about ``eps s_1`` like LAPACK's (the
    squaring only enters through ``E``, to second order), and ``f_i`` is the other factor.
    The ``f_i`` are orthogonal to about ``eps s_1^2 / (s_i s_j)``; the last one is projected
    off the others, which leaves about ``eps (s_1 / s_{m-1})^2 <= 1e-12`` and a backward
    error of about ``eps s_1 (s_1 / s_{m-1})``. Members outside the ``_GRAM_*`` floors,
    with unordered singular values (near-ties) or not finite are redone with
    ``np.linalg.svd``. Every member is computed independently of the others.
    """
    J = np.asarray(J, dtype=float)
    lead, (rows, cols) = J.shape[:-2], J.shape[-2:]
    m = min(rows, cols)
    wide = cols >= rows
    Jb = J.reshape((-1, rows, cols))
    M = Jb if wide else np.swapaxes(Jb, -1, -2)  # (k, m, max(r, c))
    with np.errstate(over="ignore", invalid="ignore"):  # huge or non-finite members are redone
        try:
            E = np.linalg.eigh(M @ np.swapaxes(M, -1, -2))[1][..., ::-1]
        except np.linalg.LinAlgError:
            E = np.zeros((Jb.shape[0], m, m))
        W = np.swapaxes(E, -1, -2) @ M
        s = np.sqrt((W * W).sum(axis=-1))
        F = W / np.maximum(s, _TINY)[..., None]
        F[:, -1] -= (np.swapaxes(F[:, :-1] @ F[:, -1, :, None], -1, -2) @ F[:, :-1])[:, 0]
        ratio = s / np.maximum(s[:, :1], _TINY)
    floor = _gram_floor(m)
    ordered = ratio[:, 1:] <= ratio[:, :-1]
    if not ((ratio >= floor).all() and ordered.all()):
        redo = ~(np.all(ratio >= floor, axis=-1) & np.all(ordered, axis=-1))
        U_r, s[redo], Vt_r = np.linalg.svd(Jb[redo], full_matrices=False)
        E[redo], F[redo] = (U_r, Vt_r) if wide else (np.swapaxes(Vt_r, -1, -2), np.swapaxes(U_r, -1, -2))
    U, Vt = (E, F) if wide else (np.swapaxes(F, -1, -2), np.swapaxes(E, -1, -2))
    return SVD(U.reshape(lead + (rows, m)), s.reshape(lead + (m,)), Vt.reshape(lead + (m, cols)))


class InverseStep(NamedTuple):
    """Result of one inverse: ``qd (..., n)`` rad/s and effective ``damping (..., m)``."""

    qd: FloatArray
    damping: FloatArray


def _param(value: FloatArray | float) -> FloatArray:
    """Parameter broadcastable against singular values ``(..., m)``."""
    return np.asarray(value, dtype=float)[..., None]


def _apply_filter(svd: SVD, xdot: FloatArray, gain: FloatArray) -> FloatArray:
    """``sum_i gain_i v_i u_i^T xdot``."""
    x = np.einsum("...im,...i->...m", svd.U, xdot)
    return np.einsum("...mn,...m->...n", svd.Vt, gain * x)


def _effective_damping(s: FloatArray, gain: FloatArray) -> FloatArray:
    """``lambda`` with ``s / (s^2 + lambda^2) = gain`` (0 where undamped)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        lam_sq = np.where(gain > 0.0, s / np.maximum(gain, _TINY) - s * s, 0.0)
    return np.sqrt(np.clip(lam_sq, 0.0, None))


def _damped_gain(s: FloatArray, lam: FloatArray) -> FloatArray:
    """DLS gain ``s / (s^2 + lam^2)``; the pseudo-inverse where ``lam == 0``."""
    denom = s * s + lam * lam
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(denom > _TINY, s / np.where(denom > _TINY, denom, 1.0), 0.0)


@dataclass(frozen=True)
class PlainInverse:
    """Undamped inverse: ``qd = J^-1 xdot`` for a square GJM (LU solve), the Moore-Penrose
    pseudo-inverse otherwise (paper eq. 3). Joint rates are unbounded near singularities."""

    name: ClassVar[str] = "inverse"
    rcond: float = 1e-12

    def solve(self, J: FloatArray, xdot: FloatArray, svd: SVD | None = None) -> InverseStep:
        m = min(J.shape[-2], J.shape[-1])
        if J.shape[-2] == J.shape[-1]:
            try:
                qd = np.linalg.solve(J, xdot[..., None])[..., 0]
                return InverseStep(qd, np.zeros(J.shape[:-2] + (m,)))
            except np.linalg.LinAlgError:
                pass  # exactly singular somewhere: fall through to the pseudo-inverse
        svd = svd if svd is not None else thin_svd(J)
        keep = svd.s > self.rcond * svd.s[..., :1]
        gain = np.where(keep, 1.0 / np.where(keep, svd.s, 1.0), 0.0)
        return InverseStep(_apply_filter(svd, xdot, gain), np.zeros_like(svd.s))

    def params(self) -> dict[str, Any]:
        return {}


@dataclass(frozen=True)
class DampedLeastSquares:
    """Constant-damping least squares (Wampler 1986; Nakamura and Hanafusa 1986), paper eq. 6:
    ``qd = J^T (J J^T + lambda^2 I)^-1 xdot = sum_i sigma_i / (sigma_i^2 + lambda^2) v_i u_i^T xdot``
    (eq. 10). ``lam`` in the units of the singular values."""

    name: ClassVar[str] = "dls"
    lam: FloatArray | float = 0.05

    def solve(self, J: FloatArray, xdot: FloatArray, svd: SVD | None = None) -> InverseStep:
        svd = svd if svd is not None else thin_svd(J)
        lam = np.broadcast_to(_param(self.lam), svd.s.shape)
        return InverseStep(_apply_filter(svd, xdot, _damped_gain(svd.s, lam)), np.array(lam))

    def params(self) -> dict[str, Any]:
        return {"lambda": self.lam}


@dataclass(frozen=True)
class AdaptiveDamping:
    """The paper's adaptive damping (eq. 16), a separate damping per singular value:
    ``lambda_i = lambda_max (1 + cos(pi sigma_i / epsilon)) / 2`` if ``sigma_i < epsilon``,
    else 0; then ``qd = sum_i sigma_i / (sigma_i^2 + lambda_i^2) v_i u_i^T xdot``.
    Continuous at ``sigma_i = epsilon``; equal to the plain inverse when all
    ``sigma_i >= epsilon``."""

    name: ClassVar[str] = "adaptive"
    lam_max: FloatArray | float = 0.0571
    epsilon: FloatArray | float = 0.0677

    def solve(self, J: FloatArray, xdot: FloatArray, svd: SVD | None = None) -> InverseStep:
        svd = svd if svd is not None else thin_svd(J)
        lam_max, eps = _param(self.lam_max), _param(self.epsilon)
        inside = svd.s < eps
        lam = np.where(inside, 0.5 * lam_max * (1.0 + np.cos(np.pi * svd.s / eps)), 0.0)
        return InverseStep(_apply_filter(svd, xdot, _damped_gain(svd.s, lam)), lam)

    def params(self) -> dict[str, Any]:
        return {"lambda_max": self.lam_max, "epsilon": self.epsilon}


@dataclass(frozen=True)
class WeightedDLS:
    """Variable damping driven by the smallest singular value, applied to all directions
    (Maciejewski and Klein 1988; Chiaverini, Siciliano and Egeland 1994; as in Orocos KDL's
    ``ChainIkSolverVel_wdls``): ``lambda = lambda_max sqrt(1 - (sigma_min / epsilon)^2)`` if
    ``sigma_min < epsilon``, else 0."""

    name: ClassVar[str] = "wdls"
    lam_max: FloatArray | float = 0.05
    epsilon: FloatArray | float = 0.1

    def solve(self, J: FloatArray, xdot: FloatArray, svd: SVD | None = None) -> InverseStep:
        svd = svd if svd is not None else thin_svd(J)
        lam_max, eps = _param(self.lam_max), _param(self.epsilon)
        s_min = svd.s[..., -1:]
        ratio = np.clip(s_min / eps, 0.0, 1.0)
        lam = np.broadcast_to(lam_max * np.sqrt(1.0 - ratio * ratio), svd.s.shape)
        return InverseStep(_apply_filter(svd, xdot, _damped_gain(svd.s, lam)), np.array(lam))

    def params(self) -> dict[str, Any]:
        return {"lambda_max": self.lam_max, "epsilon": self.epsilon}


def _clamp_max_abs(w: FloatArray, limit: FloatArray) -> FloatArray:
    """Buss and Kim's ClampMaxAbs over the last axis: scale ``w`` so ``max |w_j| <= limit``."""
    peak = np.max(np.abs(w), axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(peak > limit, limit / np.where(peak > 0.0, peak, 1.0), 1.0)
    return w * scale


@dataclass(frozen=True)
class SelectivelyDampedLS:
    """Selectively damped least squares (Buss and Kim 2005, J. Graphics Tools 10(3)), at the
    velocity level. The twist is split into its linear and angular 3-blocks (the "end
    effectors" of the original). Per singular direction i:
    ``N_i = sum_l ||u_{l,i}||``, ``M_i = sigma_i^-1 sum_j |v_{j,i}| sum_l ||J_{l,j}||``,
    ``gamma_i = min(1, N_i / M_i) gamma_max``,
    ``phi_i = ClampMaxAbs(sigma_i^-1 (u_i^T xdot) v_i, gamma_i)``; finally
    ``qd = ClampMaxAbs(sum_i phi_i, gamma_max)``. ``gamma_max`` in rad/s bounds every joint
    rate."""

    name: ClassVar[str] = "sdls"
    gamma_max: FloatArray | float = 1.0

    def solve(self, J: FloatArray, xdot: FloatArray, svd: SVD | None = None) -> InverseStep:
        svd = svd if svd is not None else thin_svd(J)
        U, s, Vt = svd
        gamma_max = _param(self.gamma_max)
        s_safe = np.maximum(s, _TINY)
        N = np.linalg.norm(U[..., :3, :], axis=-2) + np.linalg.norm(U[..., 3:, :], axis=-2)  # (..., m)
        col_norm = np.linalg.norm(J[..., :3, :], axis=-2) + np.linalg.norm(J[..., 3:, :], axis=-2)  # (..., n)
        M = np.einsum("...mn,...n->...m", np.abs(Vt), col_norm) / s_safe
        gamma = np.minimum(1.0, N / np.maximum(M, _TINY)) * gamma_max  # (..., m)
        alpha = np.einsum("...im,...i->...m", U, xdot)
        phi = (alpha / s_safe)[..., :, None] * Vt  # (..., m, n) per-direction joint rates
        phi_clamped = _clamp_max_abs(phi, gamma[..., None])
        qd = _clamp_max_abs(phi_clamped.sum(axis=-2), gamma_max)
        # Effective gain per direction, for reporting only.
        raw = np.max(np.abs(phi), axis=-1)
        clamped = np.max(np.abs(phi_clamped), axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(raw > 0.0, clamped / np.where(raw > 0.0, raw, 1.0), 1.0)
        total_raw = np.max(np.abs(phi_clamped.sum(axis=-2)), axis=-1, keepdims=True)
        total = np.max(np.abs(qd), axis=-1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = ratio * np.where(total_raw > 0.0, total / np.where(total_raw > 0.0, total_raw, 1.0), 1.0)
        return InverseStep(qd, _effective_damping(s, ratio / s_safe))

    def params(self) -> dict[str, Any]:
        return {"gamma_max": self.gamma_max}


@dataclass(frozen=True)
class SingularValueFiltering:
    """Singular value filtering (Colome and Torras 2015, IEEE/ASME Trans. Mechatronics
    20(2)): each singular value is replaced by
    ``sigma_hat = (sigma^3 + nu sigma^2 + 2 sigma + 2 sigma_0) / (sigma^2 + nu sigma + 2)``,
    which is >= ``sigma_0`` and tends to ``sigma`` for large ``sigma``; then
    ``qd = sum_i sigma_hat_i^-1 v_i u_i^T xdot``."""

    name: ClassVar[str] = "svf"
    sigma0: FloatArray | float = 0.01
    nu: FloatArray | float = 10.0

    def solve(self, J: FloatArray, xdot: FloatArray, svd: SVD | None = None) -> InverseStep:
        svd = svd if svd is not None else thin_svd(J)
        s = svd.s
        sigma0, nu = _param(self.sigma0), _param(self.nu)
        s_hat = (s**3 + nu * s**2 + 2.0 * s + 2.0 * sigma0) / (s**2 + nu * s + 2.0)
        gain = 1.0 / s_hat
        return InverseStep(_apply_filter(svd, xdot, gain), _effective_damping(s, gain))

    def params(self) -> dict[str, Any]:
        return {"sigma0": self.sigma0, "nu": self.nu}


CLASSES: dict[str, type] = {
    "inverse": PlainInverse,
    "dls": DampedLeastSquares,
    "adaptive": AdaptiveDamping,
    "wdls": WeightedDLS,
    "sdls": SelectivelyDampedLS,
    "svf": SingularValueFiltering,
    "bounded": DampedLeastSquares,  # without a joint state (no box) the bounded inverse is DLS
}


def make_inverse(name: str, **params: Any) -> Any:
    """The numpy strategy ``name`` with the engine's parameter names, defaults and checks."""
    checked = engine_inverses.make_inverse(name, **params).params()
    fields = {FIELDS.get(key, key): value for key, value in checked.items()}
    return CLASSES[name](**fields)


#: The oracle's constructor arguments of the engine's public parameter names.
FIELDS = {"lambda": "lam", "lambda_max": "lam_max"}
