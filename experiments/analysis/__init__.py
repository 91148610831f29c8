"""Analyses of trained models: the Nash analyses, the general report."""
