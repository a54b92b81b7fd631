"""Data: on-disk episode store, demonstration generation and keyframe datasets."""
