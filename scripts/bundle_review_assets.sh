#!/usr/bin/env bash
# Bundles the chart library of `mlnseq review`'s page from the npm registry into the package (never a CDN: the
# page runs with no internet): uPlot's minified script and style, with its licence, into stages/reviewing/page/.
# The two files are committed (51 KB and 2 KB), so a fresh clone and the wheel work without npm; rerun this to
# move to another version (then update UPLOT_VERSION and the checksums below, and docs/review.md).
set -euo pipefail
cd "$(dirname "$(readlink -f "$0")")/.."
UPLOT_VERSION=1.6.32
PAGE=stages/reviewing/page
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
(cd "$work" && npm pack --silent "uplot@$UPLOT_VERSION" >/dev/null && tar xzf "uplot-$UPLOT_VERSION.tgz")
cp "$work/package/dist/uPlot.iife.min.js" "$PAGE/uPlot.iife.min.js"
cp "$work/package/dist/uPlot.min.css" "$PAGE/uPlot.min.css"
cp "$work/package/LICENSE" "$PAGE/uPlot.LICENSE.txt"
echo "uplot $UPLOT_VERSION (MIT, https://github.com/leeoniya/uPlot), from npm: npm pack uplot@$UPLOT_VERSION" \
  > "$PAGE/uPlot.VERSION.txt"
sha256sum "$PAGE/uPlot.iife.min.js" "$PAGE/uPlot.min.css"
