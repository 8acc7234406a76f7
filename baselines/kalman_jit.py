"""The compiled form of baselines/kalman.py's filter: one block (T, tau, P_TT, P_TX, P_XX) as five scalars,
predicted and updated by numba functions the compiled trackers (baselines/mht, baselines/fdp) inline.  The
numpy form and its conventions are baselines/kalman.py's; this is kept apart so that importing kalman.py
loads no numba (a policy without kernels, tests/test_imports.py)."""

from __future__ import annotations

from numba import njit

# Inlined into the compiled trackers, so their arithmetic is this code's in this order: the expressions
# keep the order the trackers had when each wrote them out (a reordered sum changes the labels' last bits;
# tests/test_kalman_compiled.py holds them to kalman.py's `predict`/`update` and to filterpy).  x = (T, tau),
# P = [[p_tt, p_tx], [p_tx, p_xx]], F = [[alpha, 0], [1, 1]] (2.8), H = [0, 1], R = r.


@njit(cache=True, nogil=True, inline="always")
def kf_predict(t, tau, ptt, ptx, pxx, alpha, drift_var, interval_var):
    """`predict` on one block, the same operations in the same order."""
    if alpha == 1.0:
        return (t,  # T' = T
                tau + t,  # tau' = tau + T
                ptt + drift_var if drift_var else ptt,  # P_TT' = P_TT + Q_T
                ptt + ptx,  # P_Tx' = P_TT + P_Tx
                ptt + 2.0 * ptx + pxx + interval_var)  # P_xx' = P_TT + 2 P_Tx + P_xx + Q_tau
    return (alpha * t,  # T' = alpha T
            tau + t,  # tau' = tau + T
            alpha * alpha * ptt + drift_var,  # P_TT' = alpha^2 P_TT + Q_T
            alpha * (ptt + ptx),  # P_Tx' = alpha (P_TT + P_Tx)
            ptt + 2.0 * ptx + pxx + interval_var)  # P_xx' = P_TT + 2 P_Tx + P_xx + Q_tau


@njit(cache=True, nogil=True, inline="always")
def kf_predict_steps(t, tau, ptt, ptx, pxx, m, interval_var):
    """(2.8) m times from a filtered block in closed form (alpha = 1, Q_T = 0: T stays the same over the
    m arrivals; a period's random walk is the caller's extra terms): the m-th arrival tau_m and its
    cov(T, tau_m), var tau_m.  The block's own P_TT is unchanged."""
    pred = tau + m * t  # tau_m = tau + m T
    p_tx = ptx + m * ptt  # cov(T, tau_m) = P_Tx + m P_TT
    p_xx = pxx + 2.0 * m * ptx + m * m * ptt + m * interval_var  # var tau_m = P_xx + 2m P_Tx + m^2 P_TT + m Q_tau
    return pred, p_tx, p_xx


@njit(cache=True, nogil=True, inline="always")
def kf_update(t, tau, ptt, ptx, pxx, e, s, r):
    """`update` (2.15) on one predicted block: innovation e = y - tau, S = P_xx + R, written as `update`
    writes it (1/S once; var tau and cov(T, tau) as P R / S: no cancellation)."""
    inv_s = 1.0 / s
    g = e * inv_s  # K = P H' S^-1 = (P_Tx, P_xx) / S; g = e / S
    r_inv_s = r * inv_s
    return (t + ptx * g,  # T' = T + K_T e
            tau + pxx * g,  # tau' = tau + K_tau e
            ptt - ptx * ptx * inv_s,  # P_TT' = P_TT - P_Tx^2 / S
            ptx * r_inv_s,  # P_Tx' = P_Tx - P_Tx P_xx / S = P_Tx R / S
            pxx * r_inv_s)  # P_xx' = P_xx - P_xx^2 / S = P_xx R / S


@njit(cache=True, nogil=True, inline="always")
def kf_update_div(t, tau, ptt, ptx, pxx, e, s, r):
    """`kf_update` with every 1/S a division (e / S, P_Tx^2 / S, R / S): the form the look-ahead and start
    searches were written in; within an ulp of `kf_update`, kept so their labels stay as they were."""
    g = e / s  # g = e / S
    r_s = r / s
    return (t + ptx * g,  # T' = T + K_T e
            tau + pxx * g,  # tau' = tau + K_tau e
            ptt - ptx * ptx / s,  # P_TT' = P_TT - P_Tx^2 / S
            ptx * r_s,  # P_Tx' = P_Tx R / S
            pxx * r_s)  # P_xx' = P_xx R / S


@njit(cache=True, nogil=True, inline="always")
def drift_terms(drift, t, m):
    """A period's random walk in MK94's order (`predict`: tau' = tau + T, then T' = T + w, var w = q,
    q = (drift T)^2 for the current estimate T): what m predictions from a filtered block add to
    var tau_m, cov(T_m, tau_m) and var T_m.  tau_m = tau + m T + sum_{i<m} (m-1-i) w_i, so
    var tau_m += q sum_{k<m} k^2 = q (m-1) m (2m-1) / 6,  cov += q (m-1) m / 2,  var T_m += m q.
    With drift = 0 every term is 0.0, and adding it changes no bit."""
    q = (drift * t) * (drift * t)
    return q * ((m - 1.0) * m * (2.0 * m - 1.0) / 6.0), q * ((m - 1.0) * m / 2.0), q * m
