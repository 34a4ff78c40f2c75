"""Camera models from SPICE kernels or ISIS tables: frame cameras and line scanners (pure NumPy math)."""
