"""Per-pixel backplanes of a Level-1 cube (angles and ground point as ISIS ``phocube`` writes them)."""
