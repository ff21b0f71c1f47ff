#!/bin/bash
# Packs the wheels in .whl into .site/site.tar.xz: the wheels unpacked (a pure wheel installs by
# unzipping) and compressed with xz, for the size limit of what travels to the GPU machine.
# What the GPU machine's Python never loads is left out: extension modules built for other
# CPython versions (spottl ships 3.10-3.13), static libraries, and MuJoCo's documentation and
# MJX's test models.
# Usage: bash benchmarks/pack_site.sh [CPYTHON_TAG]   (default cpython-312; then carry .site)
set -eu
keep=${1:-cpython-312}
work=$(mktemp -d)
for w in .whl/*.whl; do
  unzip -q -o "$w" -d "$work"
  if unzip -l "$w" | grep -q '\.data/'; then echo "$w has a .data folder: install it with pip" >&2; exit 1; fi
done
find "$work" \( -name '*.cpython-3*-*.so' -o -name '*.cpython-3*-*.a' \) ! -name "*.$keep-*" -delete
find "$work" -name '*.a' -delete
rm -rf "$work"/mujoco/mjx/test_data "$work"/mujoco/doc
mkdir -p .site
tar c -C "$work" . | xz -9 -T0 > .site/site.tar.xz
rm -rf "$work"
ls -la .site/site.tar.xz
