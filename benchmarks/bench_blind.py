"""Blind deinterleavers: speed, the blind-v0 acceptance figures, modulation identification, and the
Turing Deinterleaving Challenge comparison.  Prints figures; asserts nothing.

1. speed: each policy's own compute time per pulse (runner.play) on blind-v0 episodes of 3 and 6
   sources, and genie's MAP alignment (a reference measured in the same run);
2. blind-v0 test seeds through the runner's play: per scenario, link accuracy against genie's, how
   often the number of trains found is right, V-measure;
3. modulation identification on agile-v0's scenarios made blind (no priors, 8 labels): the share of
   sources whose PRI model kind is right and the parameter errors (deint_env.modulation);
4. blind-v0 test episodes written as TDC files (float32, as the challenge's) and read back: each
   blind policy on the file (no priors: the TOA noise is measured) against the challenge baseline's
   method, HDBSCAN on the file's descriptors (here every column: TOA differences; amplitude when
   present), scored with the challenge's metrics (deint_env.tdc_scores.tdc_scores).

    nice python benchmarks/bench_blind.py [--seeds 10] [--methods cdif,sdif,pri-transform,dbscan,hdbscan]
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from deint_env.episode import Priors
from deint_env.modulation import episode_modulation_scores
from deint_env.policies import make_policy
from deint_env.runner import play, reference_accuracies
from deint_env.scenario import ScenarioSpec
from deint_env.simulate import simulate
from deint_env.suites import load_suite
from deint_env.formats import tdc
from deint_env.tdc_scores import tdc_scores

METHODS = "cdif,sdif,pri-transform,dbscan,hdbscan"


def speed(methods: list[str]) -> None:
    from deint_env.oracle import episode_genie_labels

    print("## speed (policy's own time, pulses/s)")
    for name in ("blind-n3to3-jitter0.1", "blind-n4to6-jitter0.1"):
        entry = next(e for e in load_suite("blind-v0") if e.name == name)
        ep = simulate(entry.spec, next(iter(entry.test)))
        t0 = time.perf_counter()
        episode_genie_labels(ep)
        ref = len(ep) / (time.perf_counter() - t0)
        row = []
        for m in methods:
            play(make_policy(m), ep, clustering=False)  # warm-up (numba compiles once)
            res = play(make_policy(m), ep, clustering=False)
            row.append(f"{m} {len(ep) / res.seconds:,.0f}")
        print(f"{name} ({ep.truth.n_sources} sources): " + "; ".join(row) + f"; genie alignment {ref:,.0f}")


def blind_v0(methods: list[str], seeds: int) -> None:
    print("\n## blind-v0 test seeds: link accuracy (ratio to genie's), trains counted right, V-measure, "
          "constant-PRI model right")
    for entry in load_suite("blind-v0"):
        eps = [simulate(entry.spec, s) for s in list(entry.test)[:seeds]]
        genie = np.array([reference_accuracies(ep)[0] for ep in eps])
        cells = []
        for m in methods:
            link, right, vm, kind = [], 0, [], []
            for ep in eps:
                pol = make_policy(m)
                res = play(pol, ep)
                link.append(res.metrics["link_accuracy"])
                vm.append(res.metrics["v_measure"])
                right += pol.trains_found == ep.truth.n_sources
                kind.append(episode_modulation_scores(pol.modulations(), entry.spec, ep.truth.period, res.labels,
                                                      ep.source, ep.n_labels).kind_accuracy)
            cells.append(f"{m} {np.mean(link):.3f} ({np.mean(link) / np.mean(genie):.3f}) {right}/{len(eps)} "
                         f"V {np.mean(vm):.3f} const {np.nanmean(kind):.2f}")
        print(f"{entry.name:24s} genie {np.mean(genie):.3f} | " + " | ".join(cells))


def agile_blind(methods: list[str], seeds: int) -> None:
    print("\n## modulation identification: agile-v0 scenarios made blind; for the modulated sources: share "
          "with a track, kind right among those, period / level / depth / cycle relative errors")
    for entry in load_suite("agile-v0"):
        d = entry.spec.to_dict()
        d.update(priors={"kind": "none"}, blind=True, label_budget=8, name=entry.name + "-blind")
        spec = ScenarioSpec.from_dict(d)
        cells = []
        for m in methods:
            scores, link, found = [], [], []
            for s in list(entry.test)[:seeds]:
                ep = simulate(spec, s)
                pol = make_policy(m)
                res = play(pol, ep, clustering=False)
                link.append(res.metrics["link_accuracy"])
                scores.append(episode_modulation_scores(pol.modulations(), spec, ep.truth.period, res.labels,
                                                        ep.source, ep.n_labels, modulated_only=True))
                n_mod = sum(s.modulation.kind != "constant" for s in spec.sources)
                found.append(scores[-1].n_scored / max(n_mod, 1))
            mean = lambda f: float(np.nanmean([getattr(x, f) for x in scores]))  # noqa: E731
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                cells.append(f"{m} link {np.mean(link):.3f} tracked {np.mean(found):.2f} kind "
                             f"{mean('kind_accuracy'):.2f} period "
                             f"{mean('period_rel_error'):.1e} levels {mean('level_rel_error'):.1e} depth "
                             f"{mean('depth_rel_error'):.2f} cycle {mean('cycle_rel_error'):.2f}")
        print(f"{entry.name:22s} | " + " | ".join(cells))


def tdc_comparison(methods: list[str], seeds: int) -> None:
    print("\n## blind-v0 test episodes as TDC files: the challenge's V-measure / ARI (mean over seeds)")
    budget = 32
    with tempfile.TemporaryDirectory() as tmp:
        for entry in load_suite("blind-v0"):
            res: dict[str, list[tuple[float, float]]] = {m: [] for m in methods}
            for s in list(entry.test)[:seeds]:
                path = Path(tmp) / f"{entry.name}-{s}.h5"
                tdc.train_from_episode(simulate(entry.spec, s)).write(path)
                train = tdc.read_tdc(path)
                ep = train.episode(Priors(n_labels=budget, blind=True), name=path.name)
                for m in methods:
                    pol = make_policy(f"{m}:window={len(train)}")
                    if hasattr(pol, "attach_features"):
                        pol.attach_features(train.features)
                    labels = play(pol, ep, clustering=False).labels
                    pred = np.where(labels == budget, -1, labels)
                    sc = tdc_scores(train.labels, pred)
                    res[m].append((sc["v_measure"], sc["ari"]))
            print(f"{entry.name:24s} " + " | ".join(
                f"{m} V {np.mean([v for v, _ in r]):.3f} ARI {np.mean([a for _, a in r]):.3f}" for m, r in res.items()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--methods", default=METHODS)
    ap.add_argument("--parts", default="speed,blind,agile,tdc")
    args = ap.parse_args()
    methods = args.methods.split(",")
    parts = args.parts.split(",")
    if "speed" in parts:
        speed(methods)
    if "blind" in parts:
        blind_v0(methods, args.seeds)
    if "agile" in parts:
        agile_blind([m for m in methods if m in ("cdif", "sdif", "pri-transform")], args.seeds)
    if "tdc" in parts:
        tdc_comparison(methods, args.seeds)


if __name__ == "__main__":
    main()
