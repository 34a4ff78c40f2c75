"""Photometric functions of the Moon (pure NumPy): a registry of reflectance models."""
