"""Shipped tiny relighting diffusion checkpoint (package data; see TRAINING.md)."""
