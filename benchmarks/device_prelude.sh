# Source this at the start of a command on the lent GPU machine: it installs the packages missing
# from that machine's image and puts the project on PYTHONPATH. They travel either as wheels in
# .whl or, less than half their size, as the wheels unpacked into one archive, .site/site.tar.xz
# (benchmarks/pack_site.sh). The install runs once per machine, so scripts that source this side
# by side do not race.
if [ ! -f /tmp/site/.installed ]; then
  mkdir -p /tmp/site
  if [ -f .site/site.tar.xz ]; then
    tar xJf .site/site.tar.xz -C /tmp/site || return 1
  else
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || return 1
  fi
  touch /tmp/site/.installed
fi
# MuJoCo Warp's warp-lang, packed by benchmarks/pack_warp.py into .warp/warp.tar.xz.partKofN: a call
# carries one part, the machine keeps it, and the archive unpacks once all N have arrived.
if [ ! -f /tmp/site/warp/__init__.py ] && ls .warp/warp.tar.xz.part* >/dev/null 2>&1; then
  mkdir -p /tmp/warp_parts && cp .warp/warp.tar.xz.part* /tmp/warp_parts/
  first=$(ls /tmp/warp_parts | head -1); n=${first##*of}
  if [ "$(ls /tmp/warp_parts | wc -l)" -eq "$n" ]; then
    for k in $(seq 1 "$n"); do cat "/tmp/warp_parts/warp.tar.xz.part${k}of$n"; done | tar xJ -C /tmp/site || return 1
  else
    echo "MuJoCo Warp: $(ls /tmp/warp_parts | wc -l) of $n parts here; carry the others in the next calls"
  fi
fi
export PYTHONPATH=/tmp/site:$PWD
export PYTHONUNBUFFERED=1
export XLA_PYTHON_CLIENT_PREALLOCATE=false
