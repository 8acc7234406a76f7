"""The `network` parameter every learned policy takes: "on", or "off" -- its learned output switched off.

Boards play each learned entry beside itself with `network=off` (the registry's `ablation`) on the
same episodes: the difference in score is what the learning adds (docs/design.md, 7a).  "off" means
every output logit is 0, as a zeroed output layer gives: a search then runs on its own (lmht: mht with
lmht's search settings; a beam over uniform log-probabilities), and a bare network picks its first
allowed action.
"""

from __future__ import annotations

from deint_env.errors import DeintError
from deint_env.params import Param

NETWORK = Param("network", str, "on", "off: the learned output zeroed, an ablation", choices=("on", "off"))


def network_off(network: object) -> bool:
    if network not in ("on", "off"):
        raise DeintError(f"network={network!r} is invalid: on or off (off: the learned output zeroed, an ablation)")
    return network == "off"
