"""Shipped model checkpoints, one folder per model (``config.json`` + safetensors, loaded
with ``from_pretrained``). A package only so the files install as package data."""
