"""The track network's actor in numpy: the same log-probabilities as `agents.networks.TrackExtractor`
(to float32 rounding) without torch, batched over a beam of hypotheses.

At inference one step scores one pulse against a few hypotheses' tracks: torch's per-call overhead
(tens of microseconds per module) then dominates the arithmetic, so the decoder (`agents.beam`) runs
this plain-matrix version of the checkpoint's weights instead: `scores` in numpy (the reference, checked
against torch in the tests) and `beam_scores`, the same arithmetic compiled by numba for one shared
pulse row (checked against `scores`), which the decoder calls once per pulse.  Only the scenario's own tracks are
passed in (absent tracks are masked out of the attention, the pooling and the softmax in the torch
network, so dropping them gives the same result).
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
            mu = np.float32(0.0)
            for c in range(d):
                x[a, c] += b_out[c]
                mu += x[a, c]
            mu /= d
            var = np.float32(0.0)
            for c in range(d):
                var += (x[a, c] - mu) ** 2
            inv = np.float32(1.0) / np.sqrt(var / d + np.float32(LAYER_NORM_EPS))
            for c in range(d):
                h[a, c] = (x[a, c] - mu) * inv * ln_w[c] + ln_b[c]
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
