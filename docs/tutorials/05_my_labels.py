"""Tutorial 5, step 2: label every test episode of the board with a method of your own and write the
labels in the submission format (one JSON line per episode)."""

import json

import numpy as np

from deint_env.leaderboard import Scope
from deint_env.simulate import simulate

# the board's episodes: the scenarios and seeds `deint leaderboard` was given in step 1
scope = Scope("core-v0", scenarios=("core-n2-spread4-jitter0.05", "core-n3-spread4-jitter0.05"), max_seeds=3)


def my_method(toa: np.ndarray, period: np.ndarray, phase: np.ndarray) -> list[int]:
    """Tutorial 2's follower as a plain function (any method will do: only its labels leave here):
    nearest predicted arrival, and the chosen track follows the pulse."""
    last = phase - period  # so that each track first predicts its prior phase
    labels = []
    for t in toa:
        n = np.maximum(np.round((t - last) / period), 1)  # whole periods since each track's last pulse
        track = int(np.argmin(np.abs(t - (last + n * period))))
        period[track] += 0.05 * ((t - last[track]) / n[track] - period[track])  # lean to the measured PRI
        last[track] = t
        labels.append(track)  # 0..n_labels-1 name prior tracks; -1 would say spurious
    return labels


with open("submission.jsonl", "w") as f:
    f.write(json.dumps({"format": "deint-submission", "version": 1, "suite": "core-v0", "name": "my-tracker"}) + "\n")
    for entry, seed in scope.episodes():
        episode = simulate(entry.spec, seed)  # the same pulses `deint simulate core-v0/NAME --seed S` writes
        p = episode.priors  # the public priors only: never episode.source, the truth
        labels = my_method(episode.toa, p.period.copy(), p.phase.copy())
        f.write(json.dumps({"scenario": entry.name, "seed": seed, "labels": labels}) + "\n")
print(f"labels of {len(scope.episodes())} test episodes -> submission.jsonl")
