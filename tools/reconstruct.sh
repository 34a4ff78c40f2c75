#!/usr/bin/env bash
# reconstruct.sh SETTINGS LABEL -- drop-in for PhotometryTK's reconstruct.sh (2012).
#
# Runs the legacy pipeline of lunaralbedo on a PhotometryTK settings file and writes
# the legacy output tree to albedo_LABEL/ in the current folder (albedo/, error/, DEM/,
# weightsSum/, exposure/, phase/, costFun/, weight/, image and tile lists), then the
# quarter-resolution tiles and KML (albedo_LABEL/albedo_sub4/) via `lunaralbedo export-kml`.
#
# Environment: LUNARALBEDO=/path/to/lunaralbedo overrides the command to run.
# See docs/legacy.md.
set -euo pipefail

if [ "$#" -lt 2 ]; then
    echo "Usage: $0 settingsFile labelStr" >&2
    echo "Writes the results to albedo_labelStr/ (see docs/legacy.md)." >&2
    exit 2
fi
settingsFile=$1
labelStr=$2
resDir="albedo_${labelStr}"

if [ ! -f "$settingsFile" ]; then
    echo "ERROR: File $settingsFile does not exist." >&2
    exit 2
fi

# Find the lunaralbedo command: $LUNARALBEDO, then PATH, then the repository's venv.
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
if [ -n "${LUNARALBEDO:-}" ]; then
    read -r -a lunar <<< "$LUNARALBEDO"
elif command -v lunaralbedo > /dev/null 2>&1; then
    lunar=(lunaralbedo)
elif [ -x "$here/../.venv/bin/lunaralbedo" ]; then
    lunar=("$here/../.venv/bin/lunaralbedo")
else
    echo "ERROR: the lunaralbedo command was not found (install the package or set LUNARALBEDO)." >&2
    exit 2
fi

"${lunar[@]}" solve "$settingsFile" --legacy -o "$resDir"

# Quarter-resolution tiles and KML, as the legacy script did with gdal_translate -outsize 25%
# (nearest neighbour) and image2qtree.  Skipped with a message if export-kml is unavailable.
if "${lunar[@]}" export-kml --help > /dev/null 2>&1; then
    "${lunar[@]}" export-kml "$resDir" --sub4-resampling nearest
else
    echo "NOTE: 'lunaralbedo export-kml' is not available; skipping $resDir/albedo_sub4 and the KML." >&2
fi
