"""Reinforcement and imitation learning: PPO self-play, behaviour cloning."""
