"""Physical constants and legacy conventions shared by all modules.

Frames and units used throughout the package:

* positions: km, Moon-centred body-fixed (MOON_ME when available, else IAU_MOON);
* DEM heights: metres above the reference sphere of radius :data:`MOON_RADIUS_KM`;
* longitude/latitude: degrees, planetocentric, east-positive.
"""
MOON_RADIUS_KM = 1737.4
MOON_RADIUS_M = MOON_RADIUS_KM * 1000.0

#: Length of the lookup key taken from the start of a DRG file name.
KEY_LENGTH = 11

#: The legacy program treated reflectance as zero when cos(i) is below this (``--legacy`` keeps it).
MIN_COS_INCIDENCE = 0.3

#: The solver's own limit: incidence up to 85 degrees (docs/photometry.md, "In the solver").  Below it, an
#: observation enters the albedo with the weight w (T R)^2 its signal earns; beyond it a 1-degree
#: error of the DEM normal changes R by more than 20 % (tan 85 deg = 11.4), so the model is not trusted.
MIN_COS_INCIDENCE_MODEL = 0.087
