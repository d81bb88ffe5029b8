"""Operators, one module per posing action."""
