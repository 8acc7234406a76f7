"""Tuned references: `mht-tuned:suite=core-v0` plays mht with the parameters `deint tune` chose on
core-v0's validation seeds (deint_env/tune.py), read from the checked-in preset
`baselines/presets/mht/core-v0.offline.json` (`division=` names another division's preset).

A preset is JSON data of this package, never pickled.  The built policy's `version` is the base
policy's registry version and a hash of the preset's parameters, so results are keyed on the preset
(`deint_env.policies.spec_version`): a re-tuned preset replays, an unchanged one does not.  A preset
tuned for another version of the base policy is refused: its choice was made on other labels.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from deint_env.divisions import check_division
from deint_env.errors import DeintError, shown
from deint_env.policies import Policy, canonical_spec, make_policy, policy_info

PRESET_DIR = Path(__file__).resolve().parent / "presets"


def preset_path(base: str, suite: str, division: str) -> Path:
    return PRESET_DIR / base / f"{suite}.{division}.json"


def available(base: str, suite: str | None = None) -> list[str]:
    """The specs of `base`'s tuned entry that have presets (for `suite`, or any), canonical."""
    out = []
    for path in sorted((PRESET_DIR / base).glob("*.json")):
        name, division, _ = path.name.rsplit(".", 2)
        if suite is None or name == suite:
            out.append(canonical_spec(f"{base}-tuned", {"suite": name, "division": division}))
    return out


def variants(suite: str) -> list[str]:
    """Every tuned entry's specs with a preset for `suite` (`PolicyInfo.variants`: the rows its board plays)."""
    return sorted(spec for base in {p.parent.name for p in PRESET_DIR.glob(f"*/{suite}.*.json")}
                  for spec in available(base, suite))


def load_preset(base: str, suite: str, division: str) -> dict[str, Any]:
    check_division(division)
    if not isinstance(suite, str) or not suite or "/" in suite or suite.startswith("."):
        raise DeintError(f"suite={suite!r} is invalid: a suite name")
    path = preset_path(base, suite, division)
    if not path.is_file():
        have = ", ".join(available(base)) or "none"
        raise DeintError(f"{base}-tuned has no preset for suite {suite} ({division}); presets: {have}; make one with "
                         f"`deint tune {base} --suite {suite} --division {division}`")
    try:
        preset = json.loads(path.read_text())
        version, spec, params = preset["base_version"], preset["spec"], preset["params"]
    except (ValueError, KeyError, TypeError, RecursionError) as e:  # RecursionError: JSON nested too deep
        raise DeintError(f"preset {path} is unreadable ({type(e).__name__}: {shown(str(e))})") from None
    named = {"policy": base, "suite": suite, "division": division}
    for key, want in named.items():  # a preset copied under another name would play for the wrong board
        if preset.get(key) != want:
            raise DeintError(f"preset {path}: its {key} {shown(preset.get(key))} is not {want!r}, as its path says")
    current = policy_info(base).version
    # exactly the version's type: 10.0 or True compared equal to a version 10 or 1
    if type(version) is not type(current) or version != current:
        raise DeintError(f"preset {path} was tuned for {base} version {version!r}, not the current {current!r}: "
                         f"re-tune with `deint tune {base} --suite {suite} --division {division}`")
    if not isinstance(spec, str) or spec.partition(":")[0] != base:
        raise DeintError(f"preset {path}: its spec {shown(spec)} is not a {base} spec")
    if not isinstance(params, dict):
        raise DeintError(f"preset {path}: its params {shown(params)} are not a JSON object of {base}'s parameters")
    return preset


def tuned(base: str, suite: str, division: str = "offline") -> Policy:
    """`base` built from its preset for (suite, division), its `version` keyed on the preset."""
    preset = load_preset(base, suite, division)
    policy = make_policy(preset["spec"])
    digest = hashlib.sha256(json.dumps({"params": preset["params"], "spec": preset["spec"]}, sort_keys=True)
                            .encode()).hexdigest()[:12]
    policy.version = f"{preset['base_version']}:{digest}"
    return policy


def mht_tuned(suite: str, division: str = "offline") -> Policy:
    return tuned("mht", suite, division)


def fdp_tuned(suite: str, division: str = "offline") -> Policy:
    return tuned("fdp", suite, division)


def dokf_tuned(suite: str, division: str = "offline") -> Policy:
    return tuned("dokf", suite, division)


def renewal_ml_tuned(suite: str, division: str = "offline") -> Policy:
    return tuned("renewal-ml", suite, division)


def cdif_tuned(suite: str, division: str = "offline") -> Policy:
    return tuned("cdif", suite, division)
