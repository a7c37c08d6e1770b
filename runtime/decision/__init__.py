"""The decision: patterns and the team's pattern, formation geometry, observation builders,
the rule brains, the speed clamp and ORCA filter, the pipeline that strings them together,
and one robot's ``Controller``. The robot runs it, and the trainer and ``patternrl eval``
run the very same functions over a batch of teams.
"""
