"""Races and what they measure: one race, the benchmark, the league, the strategy suite, the policy map, the control."""
