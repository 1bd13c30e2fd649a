"""Least-squares helpers of the classical pose backend: batched Kabsch rotations, the
rotation transfer map, Levenberg-Marquardt and the polish of an essential-matrix pose."""

from __future__ import annotations

import math

import numpy as np

from ..geometry import rotation_from_axis_angle, sampson_distance, skew

__all__ = ["kabsch_batch", "rotation_transfer", "levenberg_marquardt", "polish_essential"]


def kabsch_batch(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Rotations R (M, 3, 3) minimising sum ||R a - b||^2 for point sets A, B (M, k, 3)."""
    H = np.einsum("mki,mkj->mij", B, A)  # sum b a^T
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.ones((len(A), 3))
    D[:, 2] = d
    return (U * D[:, None, :]) @ Vt


def rotation_transfer(K: np.ndarray, R: np.ndarray, s: float, x0: np.ndarray, zoom: float = 1.0) -> np.ndarray:
    """Pixels of x0 mapped by ``K_sz R K_s^-1`` (focal lengths of K scaled by s in the first
    frame and by ``s * zoom`` in the second: a rotating camera that also zooms)."""
    Ks = K.copy()
    Ks[0, :2] *= s
    Ks[1, 1] *= s
    Kz = Ks.copy()
    Kz[0, :2] *= zoom
    Kz[1, 1] *= zoom
    H = Kz @ R @ np.linalg.inv(Ks)
    h0 = np.empty((len(x0), 3))
    h0[:, :2] = x0
    h0[:, 2] = 1.0
    y = h0 @ H.T
    with np.errstate(divide="ignore", invalid="ignore"):
        out = y[:, :2] / y[:, 2:3]
    bad = ~(np.isfinite(out).all(axis=1) & (y[:, 2] > 0))
    out[bad] = 1e9
    return out


def levenberg_marquardt(resid, apply, x, npar: int, *, h: float, iters: int = 40):
    """Minimise ``|resid(*x)|^2`` over increments applied by ``apply(*x, step)``, with a
    forward-difference Jacobian; deterministic."""
    r = resid(*x)
    cost = float(r @ r)
    lam = 1e-3
    for _ in range(iters):
        J = np.empty((len(r), npar))
        for k in range(npar):
            e = np.zeros(npar)
            e[k] = h
            J[:, k] = (resid(*apply(*x, e)) - r) / h
        A = J.T @ J
        g = J.T @ r
        try:
            step = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-18), -g)
        except np.linalg.LinAlgError:
            break
        xn = apply(*x, step)
        rn = resid(*xn)
        cn = float(rn @ rn)
        if math.isfinite(cn) and cn < cost:
            done = cost - cn <= 1e-10 * cost
            x, r, cost = xn, rn, cn
            lam = max(lam / 10, 1e-12)
            if done:
                break
        else:
            lam *= 10
            if lam > 1e8:
                break
    return x


def polish_essential(
    R: np.ndarray,
    t: np.ndarray,
    n0: np.ndarray,
    n1: np.ndarray,
    *,
    focal_sigma: float | None = None,
    noise: float = 1e-3,
    max_ratio: float = 1.6,
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Levenberg-Marquardt on (rotation increment, translation direction on the sphere and,
    with ``focal_sigma``, the log of a focal scale s) minimising the Sampson distance of the
    inliers, measured in units of f (pixels / f). The scale carries the prior
    ``log s ~ N(0, focal_sigma^2)``, weighted like one match with residual ``noise``.
    Returns (R, t, s, data cost)."""
    if len(n0) < 6:
        return R, t, 1.0, float("nan")
    fit_s = focal_sigma is not None
    bound = math.log(max_ratio)

    def basis(tv: np.ndarray) -> np.ndarray:
        # two unit vectors orthogonal to tv: tv x a (a the first axis tv is not near) and
        # tv x b1, written out (numpy.cross costs ~60 us per 3-vector call, most of this loop)
        x, y, z = (float(v) for v in tv)
        b1 = np.array([0.0, z, -y]) if abs(x) < 0.9 else np.array([-z, 0.0, x])
        b1 /= np.linalg.norm(b1)
        u, v, w = b1
        return np.array([[u, y * w - z * v], [v, z * u - x * w], [w, x * v - y * u]])

    def data(Rc: np.ndarray, tc: np.ndarray, ls: float) -> np.ndarray:
        sc = math.exp(ls)
        return sampson_distance(skew(tc) @ Rc, n0 / sc, n1 / sc, signed=True) * sc

    def resid(Rc: np.ndarray, tc: np.ndarray, ls: float) -> np.ndarray:
        r = data(Rc, tc, ls)
        return np.append(r, noise * ls / focal_sigma) if focal_sigma is not None else r

    def apply(Rc: np.ndarray, tc: np.ndarray, ls: float, step: np.ndarray):
        tn = tc + basis(tc) @ step[3:5]
        lsn = float(np.clip(ls + step[5], -bound, bound)) if fit_s else ls
        return rotation_from_axis_angle(step[:3]) @ Rc, tn / np.linalg.norm(tn), lsn

    R, t, ls = levenberg_marquardt(resid, apply, (R, t, 0.0), 6 if fit_s else 5, h=1e-7)
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    r = data(R, t, ls)
    return R, t, math.exp(ls), float(r @ r)
