"""Shared training utilities used by the recipes: checkpoints, loggers, evaluation."""
