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
export PYTHONPATH=/tmp/site:$PWD
export PYTHONUNBUFFERED=1
export XLA_PYTHON_CLIENT_PREALLOCATE=false
