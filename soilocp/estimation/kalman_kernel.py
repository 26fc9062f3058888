"""The observer's Kalman filter as procedural kernels over stacks of k filters, in filterpy's style
(``predict(x, P, ...)``, ``update(x, P, z, R, H)``): x (k, n), P (k, n, n), z (k, m).

One definition of each step for every caller: :class:`soilocp.estimation.observer_bank.ObserverBank` runs
them with k = 1 (the single-vehicle stage) and k = many (the batched service); the filterpy
reference (:mod:`soilocp.estimation.observer_reference`) uses :func:`condition` and :func:`outlier_variance`.
Written for small matrices (n = 12, m = 7), where numpy's per-call overhead, not arithmetic, is
the cost (issue 11): no constant is built per step, diagonals are strided views, matrix-vector
products are one matmul, in-place operations where a temporary is not needed.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np


@lru_cache(maxsize=None)
def _eye(n: int) -> np.ndarray:
    """I (n, n), built once per size (read-only): the hot path allocates no constant."""
    e = np.eye(n)
    e.flags.writeable = False
    return e


@lru_cache(maxsize=None)
def _arange(n: int) -> np.ndarray:
    a = np.arange(n)
    a.flags.writeable = False
    return a


def _diag(M: np.ndarray) -> np.ndarray:
    """The diagonals of a C-contiguous stack of square matrices M (k, n, n) as a writable (k, n) view
    (a strided slice: cheaper than the fancy index M[:, i, i] on the per-step path)."""
    n = M.shape[-1]
    return M.reshape(M.shape[0], n * n)[:, :: n + 1]


def _bmv(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Stacked matrix-vector products M (k, i, j) v (k, j) -> (k, i)."""
    return (M @ v[:, :, None])[:, :, 0]


def predict(x: np.ndarray, P: np.ndarray, A: np.ndarray, b: np.ndarray, Qc: np.ndarray, dt: np.ndarray,
            q_diag: np.ndarray | None = None):
    """ZOH prediction (eq. 34, exact series: A nilpotent) over dt (k,) > 0: returns x (k, n), P (k, n, n).

    F = I + A dt, G = b dt + A b dt^2/2, Q_d = Q dt + (A Q + Q A^T) dt^2/2 + A Q A^T dt^3/3.
    ``q_diag``: the diagonal of Qc when Qc is diagonal (ours), so that A Q is a column scaling."""
    d1 = dt[:, None]
    h2 = dt * dt / 2.0
    h3 = dt**3 / 3.0
    F = A * dt[:, None, None]
    F += _eye(x.shape[1])
    G = b * d1 + _bmv(A, b) * h2[:, None]
    AQ = A * q_diag if q_diag is not None else A @ Qc
    Qd = AQ + AQ.transpose(0, 2, 1)
    Qd *= h2[:, None, None]
    Qd += Qc * dt[:, None, None]
    Qd += (AQ @ A.transpose(0, 2, 1)) * h3[:, None, None]
    FP = F @ P
    Pn = FP @ F.transpose(0, 2, 1)
    Pn += Qd
    return _bmv(F, x) + G, Pn


def outlier_variance(innov: np.ndarray, hph: np.ndarray, r: np.ndarray, gate_sigma: float, keep: np.ndarray):
    """Measurement variance of each row (k, m) for the update of eq. 35 (docs/method.md §12): R
    where the row passes its gate (``keep``);
    for a row beyond it, the variance that puts its innovation exactly on the gate
    (nu^2 / gate^2 - H P H^T, Huber's weighting): a sensor spike moves the state by at most a
    gate's worth, and a model that is off (a traction change faster than the random walk) is
    still followed, instead of coasting on a prediction that runs away."""
    return np.where(keep, r, np.maximum(r, innov**2 / gate_sigma**2 - hph))


def gated_update(x: np.ndarray, P: np.ndarray, z: np.ndarray, r: np.ndarray, H: np.ndarray,
                 gate_sigma: float, counts: np.ndarray, patience: int, available: np.ndarray | None = None):
    """Kalman update (eq. 35 in its standard form, docs/method.md §7; Joseph form) of x (k, n),
    P (k, n, n) by z (k, m) with diagonal R (k, m) and
    H (k, m, n).  Each row is gated on its innovation (|nu| <= gate_sigma sqrt(S_ii)); a row beyond
    it is down-weighted (:func:`outlier_variance`) unless it was beyond it ``patience`` times in a
    row (then the model, not the sensor, is off: full weight again).  Rows not ``available`` (k, m)
    (a held, not a new, reading) take no part and count nothing.  Returns x, P, the new counts
    (k, m), the normalised innovation squares nu_i^2 / S_ii (k, m) of the prior and the rows taken
    at full weight (k, m).

    K = P H^T S^-1 with S = H P H^T + R;  x+ = x + K nu;  P+ = (I - K H) P (I - K H)^T + K R K^T."""
    innov = z - _bmv(H, x)
    hph = ((H @ P) * H).sum(axis=2)
    nis = innov**2 / (hph + r)
    keep = (nis <= gate_sigma**2) | (counts >= patience)
    avail = np.ones_like(keep) if available is None else available
    counts = np.where(avail, np.where(keep, 0, counts + 1), counts)
    keep &= avail
    upd = avail.any(axis=1)
    every = upd.all()  # the usual case: every vehicle has a row to take, no mask copies
    if every or upd.any():
        sel = slice(None) if every else upd
        av = avail[sel]
        Hm = H[sel] * av[:, :, None]  # a row not available: zero H row and innovation, harmless R
        y = innov[sel] * av
        rm = np.where(av, outlier_variance(innov[sel], hph[sel], r[sel], gate_sigma, keep[sel]), 1.0)
        Pu = P[sel]
        PHT = Pu @ Hm.transpose(0, 2, 1)
        S = Hm @ PHT
        d = _diag(S)
        d += rm  # in place on the strided view (``_diag(S)[...] += rm`` would also copy back)
        K = PHT @ np.linalg.inv(S)
        xn = x + _bmv(K, y) if every else x.copy()
        IKH = _eye(x.shape[1]) - K @ Hm
        Pn = IKH @ Pu @ IKH.transpose(0, 2, 1)
        Pn += (K * rm[:, None, :]) @ K.transpose(0, 2, 1)
        if every:
            x, P = xn, Pn
        else:
            xn[upd] = x[upd] + _bmv(K, y)
            P = P.copy()
            P[upd] = Pn
            x = xn
    return x, P, counts, nis, keep & avail


def condition(x: np.ndarray, P: np.ndarray, lower: np.ndarray, upper: np.ndarray, floor: float, ceiling: float):
    """Keep P (k, n, n) symmetric positive semi-definite (symmetrise, clamp variances to [floor,
    ceiling] and correlations to +-0.9999) and project x (k, n) into the physical box [lower,
    upper] (each (n,)): the state bounds of docs/method.md §12 (|mu| <= 1.5, resistance within its
    physical range).  Returns x, P (new arrays)."""
    # minimum / maximum in place of np.clip: the same values, without np.clip's dispatch overhead
    P = P + P.transpose(0, 2, 1)
    P /= 2.0
    var = np.minimum(np.maximum(_diag(P), floor), ceiling)
    sd = np.sqrt(var)
    lim = (0.9999 * sd)[:, :, None] * sd[:, None, :]
    np.minimum(P, lim, out=P)
    np.negative(lim, out=lim)
    np.maximum(P, lim, out=P)
    np.copyto(_diag(P), var)
    return np.minimum(np.maximum(x, lower), upper), P
