#!/bin/bash
# Packs the wheels in .whl into .site/site.tar.xz: the wheels unpacked (a pure wheel installs by
# unzipping) and compressed with xz, for the size limit of what travels to the GPU machine.
# Usage: bash benchmarks/pack_site.sh   (then carry .site instead of .whl)
set -eu
work=$(mktemp -d)
for w in .whl/*.whl; do
  unzip -q -o "$w" -d "$work"
  if unzip -l "$w" | grep -q '\.data/'; then echo "$w has a .data folder: install it with pip" >&2; exit 1; fi
done
mkdir -p .site
tar c -C "$work" . | xz -9 -T0 > .site/site.tar.xz
rm -rf "$work"
ls -la .site/site.tar.xz
