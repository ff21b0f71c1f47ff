#!/bin/bash
# Packs the wheels in .whl into .site/site.tar.xz: the wheels unpacked (a pure wheel installs by
# unzipping) and compressed with xz, for the size limit of what travels to the GPU machine.
# What the GPU machine's Python never loads is left out: extension modules built for other
# CPython versions (spottl ships 3.10-3.13), static libraries, MuJoCo's documentation, MJX's
# test models and MuJoCo's interactive viewers (mujoco-studio, the Filament renderer). The
# warp-lang wheel, most of the size, travels in parts instead (benchmarks/pack_warp.py).
# Usage: bash benchmarks/pack_site.sh [CPYTHON_TAG]   (default cpython-312; then carry .site)
set -eu
keep=${1:-cpython-312}
work=$(mktemp -d)
for w in .whl/*.whl; do
  case "$w" in .whl/warp_lang-*) continue ;; esac
  unzip -q -o "$w" -d "$work"
  if unzip -l "$w" | grep -q '\.data/'; then echo "$w has a .data folder: install it with pip" >&2; exit 1; fi
done
find "$work" \( -name '*.cpython-3*-*.so' -o -name '*.cpython-3*-*.a' \) ! -name "*.$keep-*" -delete
find "$work" -name '*.a' -delete
rm -rf "$work"/mujoco/mjx/test_data "$work"/mujoco/doc "$work"/mujoco/studio "$work"/mujoco_studio* "$work"/mujoco/_render_filament*
mkdir -p .site
tar c -C "$work" . | xz -9 -T0 > .site/site.tar.xz
rm -rf "$work"
ls -la .site/site.tar.xz
