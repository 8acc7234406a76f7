"""Reference policies: the paper algorithms, the floors and the oracle ceiling.

Importing this package registers them; `deint_env.make_policy("NAME:key=value")` builds one.
"""

from deint_env.policies import register_policy

register_policy("random", "baselines.floors:RandomPolicy", description="uniform random labels (floor)")
register_policy("nearest-prior", "baselines.floors:NearestPrior",
                description="nearest arrival predicted by the priors, never updated (floor)")
register_policy("genie", "baselines.genie:Genie", oracle=True,
                description="known-parameter MAP labelling from the true schedule (ceiling, oracle)")
register_policy("tree", "baselines.tree:TreeSearch",
                description="MK94 II-G: the optimal full tree search (2.19), short trains only")
register_policy("fdp", "baselines.fdp:FDP",
                description="MK94 III: forward dynamic programming with look-ahead (lookahead=3; missing, "
                            "supernumerary, dropout options of VI)")
register_policy("fdp-ll", "baselines.fdp:FDPLikelihood",
                description="fdp with likelihood-normalised costs e^2/S + log S (an improvement, not published)")
register_policy("pt-prior", "baselines.pt:PTPrior",
                description="MK94 IV-2: probabilistic teacher drawing the source from the a-priori probabilities")
register_policy("pt-post", "baselines.pt:PTPost",
                description="MK94 IV: probabilistic teacher drawing the source from the a-posteriori (4.1)-(4.3)")
register_policy("dokf", "baselines.pt:DOKFTracker",
                description="DM89 detect-then-filter on the DLM: MAP source or spurious (Theorem 1), then its KF "
                            "update; coasts through missed arrivals")
register_policy("ekf-bank", "baselines.ekf:EKFBank",
                description="CM00: EKF on the sampled pulse count (one-term Fourier smoothing), a bank of random "
                            "phase initialisations; labels from the best filter's predicted arrivals")
register_policy("ekf-coupled", "baselines.coupled:EKFCoupled",
                description="per-train EKFs on the pulse count coupled by inhibitory cells with LP's fourth-order "
                            "learning rule (12), in a bank as ekf-bank")
register_policy("agile-kf", "baselines.agile:AgileKF",
                description="agile PRIs: a bank of PRI state models per source (the one the priors name, else "
                            "constant/trend/stagger/switch) on the Kalman core, MAP assignment, coasting")
register_policy("renewal-ml", "baselines.agile:RenewalML",
                description="Young et al. 2019: ML path search (beam, fixed lag) over renewal-process PRI models "
                            "with missing and spurious pulses; blind mode: tracks born from the pulses")
