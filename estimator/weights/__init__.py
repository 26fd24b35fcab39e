"""Shipped estimator checkpoint (package data; see TRAINING.md)."""
