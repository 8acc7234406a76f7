"""The simulator's parts, run in order by `deint_env.simulate` (see its docstring)."""
