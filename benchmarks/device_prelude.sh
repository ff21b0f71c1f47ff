# Source this at the start of a command on the lent GPU machine: it installs the wheels carried
# in .whl (packages missing from that machine's image) and puts the project on PYTHONPATH. The
# install runs once per machine, so scripts that source this side by side do not race.
if [ ! -f /tmp/site/.installed ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || return 1
  touch /tmp/site/.installed
fi
export PYTHONPATH=/tmp/site:$PWD
export PYTHONUNBUFFERED=1
export XLA_PYTHON_CLIENT_PREALLOCATE=false
