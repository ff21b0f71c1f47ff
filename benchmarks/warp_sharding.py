"""Whether XLA splits MuJoCo Warp's call over devices when a batch of Zone worlds is sharded.

Builds a jitted, vmapped env step with `physics="warp"` on a batch sharded over every device
(`NamedSharding`, as the trainer and the evaluator shard), compiles it and reads, in the compiled
per-device program, how many worlds Warp's foreign call steps: the device's shard (split) or the
whole batch (gathered onto every device). On a CPU, `--virtual-devices N` makes N host devices
(set before JAX starts).

    python benchmarks/warp_sharding.py --env CarLTL0-v0 --virtual-devices 2 --batch 8
"""

from __future__ import annotations

import argparse
import os
import re
import sys

if "--virtual-devices" in sys.argv:
    count = sys.argv[sys.argv.index("--virtual-devices") + 1]
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + f" --xla_force_host_platform_device_count={count}")

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

import specrl_jax


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="CarLTL0-v0")
    parser.add_argument("--physics", default="warp", choices=["jax", "warp"])
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--virtual-devices", type=int, default=None,
                        help="host devices to create on a CPU (read before JAX starts)")
    args = parser.parse_args()
    env, params = specrl_jax.make(args.env, physics=args.physics)
    sharded = NamedSharding(Mesh(np.array(jax.devices()), ("env",)), PartitionSpec("env"))
    keys = jax.random.split(jax.random.key(0), args.batch)
    _, state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(keys, params)
    state = jax.device_put(state, sharded)
    actions = jax.device_put(jnp.zeros((args.batch, env.action_space.shape[0])), sharded)
    step = jax.jit(jax.vmap(lambda k, s, a: env.step(k, s, a, params)))
    hlo = step.lower(keys, state, actions).compile().as_text()
    worlds = sorted({int(m.group(1)) for m in re.finditer(r"%ffi_call[.\d]* = \(\w+\[(\d+),", hlo)})
    print(f"{args.env} physics={env.physics.backend}, batch {args.batch} over "
          f"{jax.device_count()} {jax.devices()[0].platform} devices (a shard: "
          f"{args.batch // jax.device_count()} worlds): "
          + (f"Warp's call steps {worlds} worlds per device" if worlds else "no foreign call"))

if __name__ == "__main__":
    main()
