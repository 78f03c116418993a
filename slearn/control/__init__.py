"""Control: the planner over the pattern library, environments, baselines."""
