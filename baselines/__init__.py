"""Reference policies: the paper algorithms, the floors and the oracle ceiling.

Importing this package registers them; `deint_env.make_policy("NAME:key=value")` builds one.
"""

from deint_env.policies import register_policy

register_policy("random", "baselines.floors:RandomPolicy", description="uniform random labels (floor)")
register_policy("nearest-prior", "baselines.floors:NearestPrior",
                description="nearest arrival predicted by the priors, never updated (floor)")
register_policy("genie", "baselines.genie:Genie", oracle=True,
                description="known-parameter MAP labelling from the true schedule (ceiling, oracle)")
