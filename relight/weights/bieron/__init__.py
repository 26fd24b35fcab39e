"""Shipped ``BieronRelighter`` checkpoint; see ``TRAINING.md`` here for how it was made."""
