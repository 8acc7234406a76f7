"""Draw the README's picture: one core-v0 episode as an analyst reads a pulse train.

Each received pulse is a dot at its time of arrival (TOA, x) and the time since the previous received
pulse (delta-TOA, y), coloured by the source that truly sent it.  Interleaved, the sources' periodic
trains are hidden in the stream's short gaps; the colours are the labels a deinterleaver must find.

    python docs/scripts/stream_picture.py            # writes docs/img/stream.png
    python docs/scripts/stream_picture.py -o x.png --scenario core-v0/core-n4-spread4-jitter0.05 --seed 1000000
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from deint_env.simulate import simulate  # noqa: E402
from deint_env.suites import resolve_scenario  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "img" / "stream.png"


def draw(scenario: str, seed: int, n_pulses: int, out: Path) -> Path:
    ep = simulate(resolve_scenario(scenario), seed)
    toa, source = ep.toa[:n_pulses], ep.source[:n_pulses]
    dtoa = np.diff(toa)
    toa, source = toa[1:], source[1:]
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(9, 5.2), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    for s in np.unique(source):
        sel = source == s
        name = "spurious" if s < 0 else f"source {s} (prior period {ep.priors.period[s]:.3g})"
        ax.scatter(toa[sel], dtoa[sel], s=10, color="0.5" if s < 0 else f"C{s}", label=name)
        ax2.eventplot([toa[sel]], lineoffsets=int(s), linelengths=0.8, colors="0.5" if s < 0 else f"C{s}")
    ax.set_ylabel("ΔTOA: time since the previous pulse")
    ax.set_title(f"{scenario}, seed {seed}: {n_pulses} received pulses by true source", fontsize=10)
    ax.legend(loc="upper right", fontsize=8, framealpha=0.9)
    ax2.set_yticks(sorted(int(s) for s in np.unique(source)))
    ax2.set_ylabel("source")
    ax2.set_xlabel("TOA (time of arrival)")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    # no date or software metadata: a rerun writes the same bytes
    fig.savefig(out, dpi=100, metadata={"Software": None})
    plt.close(fig)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="core-v0/core-n4-spread4-jitter0.05")
    p.add_argument("--seed", type=int, default=1_000_000)
    p.add_argument("--pulses", type=int, default=150, help="how many received pulses to draw")
    p.add_argument("-o", "--out", type=Path, default=OUT)
    args = p.parse_args()
    print(draw(args.scenario, args.seed, args.pulses, args.out))


if __name__ == "__main__":
    main()
