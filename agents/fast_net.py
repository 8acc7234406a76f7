"""The track network's actor in numpy: the same log-probabilities as `agents.networks.TrackExtractor`
(to float32 rounding) without torch, batched over a beam of hypotheses.

At inference one step scores one pulse against a few hypotheses' tracks: torch's per-call overhead
(tens of microseconds per module) then dominates the arithmetic, so the decoder (`agents.beam`) runs
this plain-matrix version of the checkpoint's weights instead.  Only the scenario's own tracks are
passed in (absent tracks are masked out of the attention, the pooling and the softmax in the torch
network, so dropping them gives the same result).
"""

from __future__ import annotations

from typing import Any

import numpy as np

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
