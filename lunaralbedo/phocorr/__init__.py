"""Photometric corrections of Level-1 cubes as LROC/ISIS practise them (``lronacpho``, ``lrowacphomap``)."""
