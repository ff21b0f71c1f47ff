# Source this at the start of a command on the lent GPU machine: it installs the packages missing
# from that machine's image and puts the project on PYTHONPATH. They travel either as wheels in
# .whl or, less than half their size, as the wheels unpacked into one archive, .site/site.tar.xz
# (benchmarks/pack_site.sh). The install runs once per machine, so scripts that source this side
# by side do not race. SPECRL_SITE names the install folder (default /tmp/site).
site=${SPECRL_SITE:-/tmp/site}
if [ ! -f "$site/.installed" ]; then
  mkdir -p "$site"
  if [ -f .site/site.tar.xz ]; then
    tar xJf .site/site.tar.xz -C "$site" || return 1
  else
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$site" .whl/*.whl || return 1
  fi
  touch "$site/.installed"
fi
# MuJoCo Warp's warp-lang, packed by benchmarks/pack_warp.py into .warp/warp.tar.xz.partKofN: a call
# carries one part, the machine keeps it (parts of another N are dropped), and once all N are there
# the archive unpacks beside the site, then moves in; a part from another packing fails xz's check.
parts="$site.warp_parts"
if [ ! -f "$site/.warp_installed" ] && ls .warp/warp.tar.xz.part*of* >/dev/null 2>&1; then
  carried=$(ls .warp/warp.tar.xz.part*of* | head -1); n=${carried##*of}
  mkdir -p "$parts"
  for old in "$parts"/warp.tar.xz.part*; do
    case "$old" in *of"$n") ;; *) rm -f "$old" ;; esac
  done
  cp .warp/warp.tar.xz.part*of"$n" "$parts"/
  have=$(ls "$parts"/warp.tar.xz.part*of"$n" | wc -l)
  if [ "$have" -eq "$n" ]; then
    unpack="$site.unpack.$$"
    rm -rf "$unpack" && mkdir -p "$unpack"
    if for k in $(seq 1 "$n"); do cat "$parts/warp.tar.xz.part${k}of$n" || exit 1; done | tar xJ -C "$unpack"; then
      cp -a "$unpack"/. "$site"/ && rm -rf "$unpack" && touch "$site/.warp_installed"
    else
      rm -rf "$unpack"; echo "MuJoCo Warp: the $n parts did not unpack (parts of two packings?)" >&2; return 1
    fi
  else
    echo "MuJoCo Warp: $have of $n parts here; carry the others in the next calls"
  fi
fi
export PYTHONPATH=$site:$PWD
export PYTHONUNBUFFERED=1
export XLA_PYTHON_CLIENT_PREALLOCATE=false
