"""SPICE without ISIS: kernel resolution and loading (spiceypy), table and kernel ephemerides."""
