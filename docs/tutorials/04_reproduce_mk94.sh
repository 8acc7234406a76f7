#!/usr/bin/env bash
# Tutorial 4: reproduce Moore & Krishnamurthy 1994, Figs. 4-5 (FDP's error probabilities against jitter).
set -euo pipefail

deint reproduce | grep mk94   # the MK94 experiments

# --quick: 2 test seeds, 150-pulse episodes, 3 noise levels and Delta = 1, 3 (the full run: 10 seeds,
# the papers' episode length, 9 levels, Delta = 1..5, about 25 s)
deint reproduce mk94-fig4-5 --quick --out reproduce
ls reproduce
