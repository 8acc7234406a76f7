"""baselines/blind/density.py's DBSCAN and HDBSCAN against scikit-learn's on the same data.

Data: n rows (1000, and 10001, pdw-pipeline's window) in 5 columns, eight Gaussian blobs (deviation
0.3, centres uniform in [-3, 3]) and a tenth of the rows uniform noise in [-4, 4]; DBSCAN with eps 0.3
and min_samples 5, HDBSCAN with min_cluster_size 5.  Each figure is the best of --repeats wall times
(scikit-learn imported beforehand, untimed; so is density.py), then whether the labels are equal, label
for label.  Prints figures; asserts nothing.

    python benchmarks/bench_density.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import best_of  # noqa: E402

from baselines.blind.density import dbscan, hdbscan  # noqa: E402


def data(n: int, d: int = 5, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-3, 3, (8, d))
    x = centres[rng.integers(0, 8, n)] + rng.normal(0, 0.3, (n, d))
    x[: n // 10] = rng.uniform(-4, 4, (n // 10, d))
    return x


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per figure, the best kept (default 3)")
    args = ap.parse_args()
    from sklearn.cluster import DBSCAN, HDBSCAN

    runs = {"dbscan": (lambda x: dbscan(x, 0.3, 5), lambda x: DBSCAN(eps=0.3, min_samples=5).fit_predict(x)),
            "hdbscan": (lambda x: hdbscan(x, 5), lambda x: HDBSCAN(min_cluster_size=5, copy=True).fit_predict(x))}
    print(f"{'method':8s} {'n':>6s} {'ours s':>8s} {'sklearn s':>10s} {'ratio':>6s}  labels equal")
    for n in (1000, 10001):
        x = data(n)
        for name, (ours, theirs) in runs.items():
            t_ours, t_theirs = best_of(lambda: ours(x), args.repeats), best_of(lambda: theirs(x), args.repeats)
            same = np.array_equal(ours(x), theirs(x))
            print(f"{name:8s} {n:6d} {t_ours:8.3f} {t_theirs:10.3f} {t_ours / t_theirs:6.2f}  {same}")


if __name__ == "__main__":
    main()
