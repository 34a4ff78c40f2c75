"""Ingest: ISIS cubes + SPICE + DEM -> DRG GeoTIFFs, position files and a settings file."""
