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

#: The legacy program treated reflectance as zero when cos(i) is below this.
MIN_COS_INCIDENCE = 0.3
