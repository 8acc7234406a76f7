"""`mht`: a gated multi-hypothesis tracker (hypothesis-oriented MHT as a beam search) on the DLM of MK94.
How it works -- gating, scores, look-ahead, beam, N-scan pruning, track start, prior test, rates -- is
docs/mht.md.

Modules: `policy` (the `MHT` policy: parameters, the start's tests and restarts, batching), `kernels`
(the compiled beam: `step`, `rates`, `count`, `prior_ahead`, the driver), `start` (the compiled track
start: `initiate`), `scorer` (the learned scorer hook of `lmht`: `Scorer`, `mlp`, its features),
`state` (block fields, constants, the work arrays `Beam`, `Scratch`, `Settings`).  Re-exported here:
the kernel API a tracker built on mht's beam uses (agents/lmht.py).
"""

from baselines.mht.kernels import count, prior_ahead, rates, step
from baselines.mht.policy import MHT
from baselines.mht.scorer import FEATURE_VERSION, FEATURES, N_FEATURES, Scorer, mlp
from baselines.mht.start import initiate
from baselines.mht.state import P_TT, P_TX, P_XX, PERIOD, TAU, Beam, Scratch, Settings

__all__ = ["FEATURES", "FEATURE_VERSION", "MHT", "N_FEATURES", "PERIOD", "P_TT", "P_TX", "P_XX", "TAU", "Beam",
           "Scorer", "Scratch", "Settings", "count", "initiate", "mlp", "prior_ahead", "rates", "step"]
