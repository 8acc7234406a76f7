"""Blind deinterleavers (unknown number of sources, no priors): the electronic-warfare classics.

- `histograms`: Mardia's CDIF (IEE Proc. F 136(4), 1989) and Milojevic & Popovic's SDIF (IEE Proc. F
  139(1), 1992) difference histograms with their thresholds;
- `pri_transform`: Nishiguchi & Kobayashi's jitter-robust PRI transform (IEEE TAES 36(2), 2000);
- `search`: sequence search, extracting a train by its PRI (tolerant of missing pulses and jitter);
- `pipeline`: detect a PRI, extract its train, repeat; stagger sub-trains merged; MAP re-association;
- `pri_models`: the PRI model of each train (constant, stagger, sliding, sinusoidal);
- `clustering`: DBSCAN / HDBSCAN on pulse descriptors (the Turing Deinterleaving Challenge baseline);
- `policy`: all of them as windowed blind-mode policies.
"""
