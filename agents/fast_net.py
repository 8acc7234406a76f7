"""The track network's actor in numpy: the same log-probabilities as `agents.networks.TrackExtractor`
(to float32 rounding) without torch, batched over a beam of hypotheses.

At inference one step scores one pulse against a few hypotheses' tracks: torch's per-call overhead
(tens of microseconds per module) then dominates the arithmetic, so the decoder (`agents.beam`) runs
this plain-matrix version of the checkpoint's weights instead: `scores` in numpy (the reference, checked
against torch in the tests) and `beam_scores`, the same arithmetic compiled by numba for one shared
pulse row (checked against `scores`), which the decoder calls once per pulse.  Only the scenario's own tracks are
passed in (absent tracks are masked out of the attention, the pooling and the softmax in the torch
network, so dropping them gives the same result).

The `agent` policy (`agents.policy.AgentPolicy`) plays a checkpoint's greedy labels through
`TrackLogits` (the track network) or `MLPLogits` (SB3's MlpPolicy), one compiled call per step for the
pulses of every episode it plays in lock-step.  Their kernels multiply with plain loops, not BLAS: a
BLAS product may sum in another order for another number of rows (a gemv path for one row, blocked
kernels for many), and a row's logits must not depend on which other episodes share its batch, so
that a batched play gives exactly the labels of playing each episode alone.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit

PREFIX = "features_extractor."
LAYER_NORM_EPS = 1e-5  # torch.nn.LayerNorm's default


def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0, out=x)


class NumpyTrackNet:
    """`log_probs(tracks (B, n, F), pulse (B or 1, G))` -> (B, n + 1): log-softmax over the n tracks
    and spurious (last column), as the torch network's masked logits give.  One pulse row is shared
    by all B rows (a beam's hypotheses all describe the same pulse)."""

    def __init__(self, tensors: dict[str, Any], heads: int):
        w = {k[len(PREFIX):] if k.startswith(PREFIX) else k:
             np.ascontiguousarray(v.detach().cpu().numpy() if hasattr(v, "detach") else v, dtype=np.float32)
             for k, v in tensors.items()}
        # Linear layers as (in, out) matrices so x @ W needs no transpose per call.
        self.e0, self.b0 = w["embed.0.weight"].T.copy(), w["embed.0.bias"]
        self.e2, self.b2 = w["embed.2.weight"].T.copy(), w["embed.2.bias"]
        self.attention = "attention.in_proj_weight" in w
        d = self.e2.shape[1]
        if self.attention:
            self.heads = int(heads)
            if d % self.heads:
                raise ValueError(f"d_model {d} is not divisible by {heads} heads")
            self.w_in, self.b_in = w["attention.in_proj_weight"].T.copy(), w["attention.in_proj_bias"]
            self.w_out, self.b_out = w["attention.out_proj.weight"].T.copy(), w["attention.out_proj.bias"]
            self.ln_w, self.ln_b = w["norm.weight"], w["norm.bias"]
        self.s0, self.sb0 = w["score.0.weight"].T.copy(), w["score.0.bias"]
        self.s2, self.sb2 = w["score.2.weight"].T.copy(), w["score.2.bias"]
        self.p0, self.pb0 = w["pool.0.weight"].T.copy(), w["pool.0.bias"]
        self.sp, self.spb = w["spurious.weight"].T.copy(), w["spurious.bias"]
        # The value head: with DAgger's consistency loss, the logit that the hypothesis is still right.
        self.v, self.vb = (w.get("value_net.weight"), w.get("value_net.bias"))
        self.d_model = d
        self.n_token = self.e0.shape[0]  # F + G
        self._compiled: tuple | None = None  # the arguments of `_beam_scores`, laid out once

    def beam_scores(self, tracks: np.ndarray, pulse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`scores` of k hypotheses sharing one pulse row (G,), in one numba call (the beam's per-pulse path)."""
        if self._compiled is None:
            g = pulse.shape[0]
            f = self.n_token - g
            d = self.d_model
            empty2, empty1 = np.zeros((1, 1), np.float32), np.zeros(1, np.float32)
            att = (self.w_in, self.b_in, self.w_out, self.b_out, self.ln_w, self.ln_b) if self.attention else (
                empty2, empty1, empty2, empty1, empty1, empty1)
            v = self.v.T.copy() if self.v is not None else np.zeros((d, 1), np.float32)
            vb = float(self.vb[0]) if self.v is not None else 0.0
            self._compiled = (np.ascontiguousarray(self.e0[:f]), np.ascontiguousarray(self.e0[f:]), self.b0, self.e2,
                              self.b2, self.attention, getattr(self, "heads", 1), *att, self.s0, self.sb0, self.s2,
                              self.p0, self.pb0, self.sp, np.array([self.sb2[0], self.spb[0], vb]), v)
        return _beam_scores(tracks, pulse, *self._compiled)

    def logits(self, tracks: np.ndarray, pulse: np.ndarray) -> np.ndarray:
        return self.forward(tracks, pulse)[0]

    def forward(self, tracks: np.ndarray, pulse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(logits (B, n + 1), value latent (B, d_model))."""
        b, n, f = tracks.shape
        g = pulse.shape[1]
        d = self.d_model
        # embed(cat(token, pulse)) = token @ W[:F] + pulse @ W[F:] (the pulse part once per row)
        h = tracks.reshape(b * n, f) @ self.e0[:f]
        h = h.reshape(b, n, d) + (pulse @ self.e0[f:] + self.b0)[:, None, :]
        h = _relu(h)
        h = _relu(h @ self.e2 + self.b2)
        if self.attention:
            nh, dh = self.heads, d // self.heads
            qkv = (h @ self.w_in + self.b_in).reshape(b, n, 3, nh, dh)
            q = qkv[:, :, 0].transpose(0, 2, 1, 3)  # (b, heads, n, dh)
            k = qkv[:, :, 1].transpose(0, 2, 3, 1)  # (b, heads, dh, n)
            v = qkv[:, :, 2].transpose(0, 2, 1, 3)
            att = (q @ k) * np.float32(1.0 / np.sqrt(dh))
            att = np.exp(att - att.max(-1, keepdims=True))
            att /= att.sum(-1, keepdims=True)
            a = (att @ v).transpose(0, 2, 1, 3).reshape(b, n, d) @ self.w_out + self.b_out
            x = h + a
            mu = x.mean(-1, keepdims=True)
            xc = x - mu
            var = (xc * xc).mean(-1, keepdims=True)
            h = xc / np.sqrt(var + np.float32(LAYER_NORM_EPS)) * self.ln_w + self.ln_b
        scores = (_relu(h @ self.s0 + self.sb0) @ self.s2)[..., 0] + self.sb2[0]
        pooled = _relu(h.mean(1) @ self.p0[:d] + h.max(1) @ self.p0[d:2 * d] + (pulse @ self.p0[2 * d:] + self.pb0))
        spurious = pooled @ self.sp + self.spb
        return np.concatenate([scores, spurious], axis=1), pooled

    def log_probs(self, tracks: np.ndarray, pulse: np.ndarray) -> np.ndarray:
        return self.scores(tracks, pulse)[0]

    def scores(self, tracks: np.ndarray, pulse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(log-probabilities (B, n + 1), log sigmoid of the value head (B,))."""
        z, pooled = self.forward(tracks, pulse)
        z = z - z.max(1, keepdims=True)
        logp = z - np.log(np.exp(z).sum(1, keepdims=True))
        v = (pooled @ self.v[0] + self.vb[0]) if self.v is not None else np.zeros(len(z), np.float32)
        return logp, -np.logaddexp(0.0, -v)


@njit(cache=True, inline="always")
def _layer_norm_row(x, h, a, ln_w, ln_b):
    """h[a] = LayerNorm(x[a]) in float32, summed in index order (torch.nn.LayerNorm: biased variance)."""
    d = x.shape[1]
    mu = np.float32(0.0)
    for c in range(d):
        mu += x[a, c]
    mu /= d
    var = np.float32(0.0)
    for c in range(d):
        var += (x[a, c] - mu) ** 2
    inv = np.float32(1.0) / np.sqrt(var / d + np.float32(LAYER_NORM_EPS))
    for c in range(d):
        h[a, c] = (x[a, c] - mu) * inv * ln_w[c] + ln_b[c]


@njit(cache=True)
def _beam_scores(tracks, pulse, e0t, e0p, b0, e2, b2, attention, heads, w_in, b_in, w_out, b_out, ln_w, ln_b,
                 s0, sb0, s2, p0, pb0, sp, consts, v):
    """`NumpyTrackNet.scores` for one shared pulse row (G,) in one compiled call: the same arithmetic
    (float32 matrix products through BLAS), without numpy's per-call overhead.  consts = (score.2
    bias, spurious bias, value bias)."""
    k, n, f = tracks.shape
    d = b0.shape[0]
    rows = k * n
    pe = np.dot(pulse.reshape(1, -1), e0p)[0] + b0
    h = np.dot(np.ascontiguousarray(tracks.reshape(rows, f)), e0t)
    for a in range(rows):
        for c in range(d):
            h[a, c] = max(h[a, c] + pe[c], np.float32(0.0))
    h = np.dot(h, e2)
    for a in range(rows):
        for c in range(d):
            h[a, c] = max(h[a, c] + b2[c], np.float32(0.0))
    if attention:
        dh = d // heads
        scale = np.float32(1.0 / np.sqrt(dh))
        qkv = np.dot(h, w_in)
        for a in range(rows):
            for c in range(3 * d):
                qkv[a, c] += b_in[c]
        att = np.zeros((rows, d), np.float32)
        s = np.empty(n, np.float32)
        for r in range(k):
            for hh in range(heads):
                o = hh * dh
                for i in range(n):
                    qi = r * n + i
                    top = np.float32(-np.inf)
                    for j in range(n):
                        kj = r * n + j
                        acc = np.float32(0.0)
                        for c in range(dh):
                            acc += qkv[qi, o + c] * qkv[kj, d + o + c]
                        s[j] = acc * scale
                        top = max(top, s[j])
                    tot = np.float32(0.0)
                    for j in range(n):
                        s[j] = np.exp(s[j] - top)
                        tot += s[j]
                    for j in range(n):
                        wj = s[j] / tot
                        vj = r * n + j
                        for c in range(dh):
                            att[qi, o + c] += wj * qkv[vj, 2 * d + o + c]
        x = h + np.dot(att, w_out)
        for a in range(rows):
            for c in range(d):
                x[a, c] += b_out[c]
            _layer_norm_row(x, h, a, ln_w, ln_b)
    sc = np.dot(h, s0)
    for a in range(rows):
        for c in range(d):
            sc[a, c] = max(sc[a, c] + sb0[c], np.float32(0.0))
    track_logit = np.dot(sc, s2)
    pooled_in = np.empty((k, 2 * d + pulse.shape[0]), np.float32)
    for r in range(k):
        for c in range(d):
            tot = np.float32(0.0)
            top = np.float32(-np.inf)
            for i in range(n):
                y = h[r * n + i, c]
                tot += y
                top = max(top, y)
            pooled_in[r, c] = tot / n
            pooled_in[r, d + c] = top
        pooled_in[r, 2 * d:] = pulse
    pooled = np.dot(pooled_in, p0)
    for r in range(k):
        for c in range(d):
            pooled[r, c] = max(pooled[r, c] + pb0[c], np.float32(0.0))
    spur = np.dot(pooled, sp)
    value = np.dot(pooled, v)
    logp = np.empty((k, n + 1))
    consistent = np.empty(k)
    for r in range(k):
        for i in range(n):
            logp[r, i] = track_logit[r * n + i, 0] + consts[0]
        logp[r, n] = spur[r, 0] + consts[1]
        top = logp[r].max()
        tot = 0.0
        for i in range(n + 1):
            tot += np.exp(logp[r, i] - top)
        lse = top + np.log(tot)
        for i in range(n + 1):
            logp[r, i] -= lse
        z = value[r, 0] + consts[2]
        consistent[r] = -np.logaddexp(0.0, -z) if z > -30.0 else z
    return logp, consistent


# ---------------------------------------------------------------------------------------------------
# batch-invariant forward passes for the `agent` policy (module doc)
# ---------------------------------------------------------------------------------------------------
MASKED = np.float32(-1e8)  # an absent track's logit, as agents.networks.MASKED


@njit(cache=True)
def _dense(x, w, b, act):
    """act(x @ w + b) (act: 0 none, 1 relu, 2 tanh).  Every output is b, then + x[r, k] * w[k, c] in k
    order, each product and sum rounded (no fused multiply-add, no reordering): the same bits whichever
    loop (a block of eight rows, or one row) computes it, so a row's result does not depend on the rows
    beside it.  Eight rows share each load of w."""
    rows, n_in = x.shape
    n_out = w.shape[1]
    out = np.empty((rows, n_out), np.float32)
    for r in range(rows):
        out[r] = b
    r = 0
    while r + 8 <= rows:
        a0, a1, a2, a3, a4, a5, a6, a7 = (out[r], out[r + 1], out[r + 2], out[r + 3], out[r + 4], out[r + 5],
                                          out[r + 6], out[r + 7])
        for k in range(n_in):
            x0, x1, x2, x3 = x[r, k], x[r + 1, k], x[r + 2, k], x[r + 3, k]
            x4, x5, x6, x7 = x[r + 4, k], x[r + 5, k], x[r + 6, k], x[r + 7, k]
            wk = w[k]
            for c in range(n_out):  # contiguous rows of w: the compiler vectorises this loop
                wc = wk[c]
                a0[c] += x0 * wc
                a1[c] += x1 * wc
                a2[c] += x2 * wc
                a3[c] += x3 * wc
                a4[c] += x4 * wc
                a5[c] += x5 * wc
                a6[c] += x6 * wc
                a7[c] += x7 * wc
        r += 8
    for q in range(r, rows):
        a0 = out[q]
        for k in range(n_in):
            x0 = x[q, k]
            wk = w[k]
            for c in range(n_out):
                a0[c] += x0 * wk[c]
    if act == 1:
        for q in range(rows):
            for c in range(n_out):
                out[q, c] = max(out[q, c], np.float32(0.0))
    elif act == 2:
        for q in range(rows):
            for c in range(n_out):
                out[q, c] = np.tanh(out[q, c])
    return out


@njit(cache=True)
def _track_logits(tracks, pulse, n, e0t, e0p, b0, e2, b2, attention, heads, w_in, b_in, w_out, b_out, ln_w, ln_b,
                  s0, sb0, s2, p0, pb0, sp, consts):
    """The track network's logits (K, M + 1) for K episodes' observations: row r's first n[r] tracks of
    tracks (K, M, F), its pulse row (K, G); absent tracks get MASKED, spurious is column M.  The
    arithmetic of `NumpyTrackNet.forward`; the tracks of all rows go through each layer together, and
    every row's numbers depend on that row alone (`_dense`; the attention and pooling loops run per row)."""
    k, m, f = tracks.shape
    d = b0.shape[0]
    start = np.zeros(k + 1, np.int64)
    for r in range(k):
        start[r + 1] = start[r] + n[r]
    tokens = np.empty((start[k], f), np.float32)
    for r in range(k):
        tokens[start[r]:start[r + 1]] = tracks[r, :n[r]]
    # embed(cat(token, pulse)) = token @ W[:F] + (pulse @ W[F:] + b): the pulse part once per row
    pe = _dense(pulse, e0p, b0, 0)
    h = _dense(tokens, e0t, np.zeros(d, np.float32), 0)
    for r in range(k):
        for i in range(start[r], start[r + 1]):
            for c in range(d):
                h[i, c] = max(h[i, c] + pe[r, c], np.float32(0.0))
    h = _dense(h, e2, b2, 1)
    if attention:
        dh = d // heads
        scale = np.float32(1.0 / np.sqrt(dh))
        qkv = _dense(h, w_in, b_in, 0)
        att = np.zeros((start[k], d), np.float32)
        s = np.empty(m, np.float32)
        for r in range(k):
            lo, hi = start[r], start[r + 1]
            for hh in range(heads):
                o = hh * dh
                for i in range(lo, hi):
                    qi = qkv[i, o:o + dh]
                    top = np.float32(-np.inf)
                    for j in range(lo, hi):
                        kj = qkv[j, d + o:d + o + dh]
                        acc = np.float32(0.0)
                        for c in range(dh):
                            acc += qi[c] * kj[c]
                        s[j - lo] = acc * scale
                        top = max(top, s[j - lo])
                    tot = np.float32(0.0)
                    for j in range(hi - lo):
                        s[j] = np.exp(s[j] - top)
                        tot += s[j]
                    ai = att[i, o:o + dh]
                    for j in range(lo, hi):
                        wj = s[j - lo] / tot
                        vj = qkv[j, 2 * d + o:2 * d + o + dh]
                        for c in range(dh):
                            ai[c] += wj * vj[c]
        x = _dense(att, w_out, b_out, 0)
        for a in range(start[k]):
            for c in range(d):
                x[a, c] += h[a, c]
            _layer_norm_row(x, h, a, ln_w, ln_b)
    track_logit = _dense(_dense(h, s0, sb0, 1), s2, consts[:1], 0)
    pooled_in = np.empty((k, 2 * d + pulse.shape[1]), np.float32)
    out = np.full((k, m + 1), MASKED)
    for r in range(k):
        lo, hi = start[r], start[r + 1]
        for i in range(lo, hi):
            out[r, i - lo] = track_logit[i, 0]
        for c in range(d):
            tot = np.float32(0.0)
            top = np.float32(-np.inf)
            for i in range(lo, hi):
                tot += h[i, c]
                top = max(top, h[i, c])
            pooled_in[r, c] = tot / (hi - lo)
            pooled_in[r, d + c] = top
        pooled_in[r, 2 * d:] = pulse[r]
    spurious = _dense(_dense(pooled_in, p0, pb0, 1), sp, consts[1:2], 0)
    for r in range(k):
        out[r, m] = spurious[r, 0]
    return out


class TrackLogits:
    """The track network's actor logits for a batch of token observations, batch-invariant (module doc).
    `__call__(tracks (K, M, F), pulse (K, G), n (K,))` -> (K, M + 1) float32: absent tracks MASKED, as
    the torch network's logits (to float32 rounding)."""

    def __init__(self, net: NumpyTrackNet, n_features: int):
        empty2, empty1 = np.zeros((1, 1), np.float32), np.zeros(1, np.float32)
        att = (net.w_in, net.b_in, net.w_out, net.b_out, net.ln_w, net.ln_b) if net.attention else (
            empty2, empty1, empty2, empty1, empty1, empty1)
        f = n_features  # the embedding's rows: F token features, then G pulse features
        self._weights = (np.ascontiguousarray(net.e0[:f]), np.ascontiguousarray(net.e0[f:]), net.b0, net.e2, net.b2,
                         net.attention, getattr(net, "heads", 1), *att, net.s0, net.sb0, net.s2, net.p0, net.pb0,
                         net.sp, np.array([net.sb2[0], net.spb[0]], np.float32))

    def __call__(self, tracks: np.ndarray, pulse: np.ndarray, n: np.ndarray) -> np.ndarray:
        return _track_logits(np.ascontiguousarray(tracks, np.float32), np.ascontiguousarray(pulse, np.float32),
                             np.asarray(n, np.int64), *self._weights)


ACTIVATIONS = {"relu": 1, "tanh": 2}


class MLPLogits:
    """SB3's MlpPolicy actor (`net_arch` hidden layers of `activation`, then the action layer) on flat
    observations (K, D) -> logits (K, A) float32, batch-invariant (module doc)."""

    def __init__(self, tensors: dict[str, Any], net_arch: list[int], activation: str):
        w = {k: np.asarray(v.detach().cpu().numpy() if hasattr(v, "detach") else v, np.float32)
             for k, v in tensors.items()}
        act = ACTIVATIONS[activation]
        self._layers = [(np.ascontiguousarray(w[f"mlp_extractor.policy_net.{2 * i}.weight"].T),
                         w[f"mlp_extractor.policy_net.{2 * i}.bias"], act) for i in range(len(net_arch))]
        self._layers.append((np.ascontiguousarray(w["action_net.weight"].T), w["action_net.bias"], 0))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.ascontiguousarray(x, np.float32)
        for weight, bias, act in self._layers:
            x = _dense(x, weight, bias, act)
        return x
