#!/bin/sh
# Re-creates the photos and calibration files in this directory from Debian 12's opencv-doc
# package (4.6.0+dfsg-12), byte for byte (checked against SHA256SUMS). See ATTRIBUTION.md.
# Needs apt-get (after 'apt-get update') and dpkg. Usage: sh test/data/photos/fetch.sh
set -eu
here=$(cd "$(dirname "$0")" && pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
cd "$tmp"
apt-get download opencv-doc
deb=$(ls opencv-doc_*.deb)
case "$deb" in
  opencv-doc_4.6.0+dfsg-12_all.deb) ;;
  *) echo "note: got $deb, not 4.6.0+dfsg-12; the checksums below may fail" >&2 ;;
esac
dpkg -x "$deb" x
doc=x/usr/share/doc/opencv-doc
# checkerboard (9 x 6 inner corners, 25 mm squares); left10.jpg is not in the package
for i in 01 02 03 04 05 06 07 08 09 11 12 13 14; do
  cp "$doc/examples/data/left$i.jpg" "$here/"
done
cp "$doc/examples/data/left_intrinsics.yml" "$here/"
# ArUco / ChArUco tutorial photos and the camera files their tutorials use
for f in choriginal.jpg gboriginal.png singlemarkersoriginal.jpg; do
  cp "$doc/opencv4/html/$f" "$here/"
done
for f in tutorial_camera_charuco.yml tutorial_camera_params.yml tutorial_dict.yml; do
  cp "$doc/examples/aruco/$f" "$here/"
done
cd "$here" && sha256sum -c SHA256SUMS
