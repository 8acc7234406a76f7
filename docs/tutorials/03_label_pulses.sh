#!/usr/bin/env bash
# Tutorial 3: label a pulse file of your own, with priors (anchored) and without (blind), and score it.
set -euo pipefail

python 03_make_pulses.py

# anchored: fdp tracks the three prior sources; label i means prior source i, -1 spurious
deint label pulses.csv --priors priors.json --policy fdp -o labels.csv
head -4 labels.csv
# the policy never saw the file's source column; score compares against it
deint score labels.csv --truth pulses.csv

# fdp assumes every pulse arrives; dropout=true coasts a track through missed arrivals (MK94 VI-C-3)
deint label pulses.csv --priors priors.json --policy fdp:dropout=true -o coast.csv
deint score coast.csv --truth pulses.csv

# blind: no priors, only the number of sources; cdif finds the PRIs from difference histograms.
# Label names are arbitrary here, so --blind scores links (is each pulse's predecessor in its source right?)
deint label pulses.csv --n-sources 3 --policy cdif -o blind.csv
deint score blind.csv --truth pulses.csv --blind
