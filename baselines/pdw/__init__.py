"""Blind deinterleavers of pulse descriptor words (PDWs): time of arrival, centre frequency, pulse width,
angle of arrival and amplitude, as the Turing Deinterleaving Challenge's files carry them (Gunn et al.,
"The Turing Synthetic Radar Dataset: a dataset for pulse deinterleaving", arXiv:2602.03856).

- `pdw-hdbscan` (`baselines.pdw.hdbscan`): the challenge's baseline, HDBSCAN (as scikit-learn defines it) on the
  PDWs of each window;
- `pdw-pipeline` (`baselines.pdw.pipeline`): the classical EW pipeline, parameter cells first, then PRI
  analysis and sequence search within each cell, then cells of one agile emitter merged.

Both read the descriptors from the observations (`baselines.pdw.policy.PDWPolicy`) and refuse an episode
without them.  docs/pdw.md describes them.
"""
