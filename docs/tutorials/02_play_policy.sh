#!/usr/bin/env bash
# Tutorial 2, after `pip install -e 02_policy`: the installed policy is listed and plays like a shipped one.
set -euo pipefail

# the registry found it through the entry point (the header line, then its row)
deint policies | grep -E '^(policy|follower) '

# follower with its default gain and with gain=0.5 (NAME:key=value is passed to __init__), beside the
# floors (nearest-prior, random), fdp and the genie ceiling, on 3 validation seeds of one scenario
deint run --scenario core-v0/core-n3-spread4-jitter0.05 --split validation --max-seeds 3 \
    --policy follower --policy follower:gain=0.5 --policies nearest-prior,fdp,genie,random \
    --out runs/follower.jsonl --no-progress
