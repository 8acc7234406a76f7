"""Tutorial 3, step 1: a pulse file and a priors file from a generator of your own (not deint's)."""

import json

import numpy as np

rng = np.random.default_rng(7)
periods = np.array([9.7, 14.2, 23.9])  # the true PRIs of three emitters
phases = np.array([2.0, 5.5, 11.0])  # each one's first emission
jitter = 0.1  # white TOA noise (standard deviation), the same time unit
duration = 3000.0

toa, source = [], []
for i, (T, phi) in enumerate(zip(periods, phases)):
    t = np.arange(phi, duration, T) + rng.normal(0.0, jitter, int(np.ceil((duration - phi) / T)))
    keep = rng.random(t.size) > 0.05  # 5 % of the pulses are missed by the receiver
    toa.append(t[keep])
    source.append(np.full(keep.sum(), i))
toa, source = np.concatenate(toa), np.concatenate(source)
order = np.argsort(toa)  # a receiver sees the pulses in time order
np.savetxt("pulses.csv", np.column_stack([toa[order], source[order]]), delimiter=",",
           header="toa,source", comments="", fmt=["%.6f", "%d"])

# What a policy may know: an emitter library's nominal PRIs (here 1 % off the truth) and rough phases,
# with their uncertainties, the noise level and the channel statistics.
priors = {
    "period": (periods * np.array([1.01, 0.99, 1.01])).tolist(),
    "phase": (phases + 0.3).tolist(),
    "period_std": (0.02 * periods).tolist(),
    "phase_std": [1.0, 1.0, 1.0],
    "jitter_std": jitter,
    "missing_prob": 0.05,
    "spurious_rate": 0.0,
}
with open("priors.json", "w") as f:
    json.dump(priors, f, indent=1)
print(f"{toa.size} pulses of {periods.size} sources -> pulses.csv, priors.json")
