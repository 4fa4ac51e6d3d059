"""The one-axis device mesh training and the closed-loop rollouts place their arrays on, and
several processes working together (initialised from the environment, meeting at barriers)."""

from __future__ import annotations

import os

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

# XLA:CPU's concurrency-optimised scheduler may order independent collectives differently in
# each process, and Gloo then fails ("Received data size doesn't match expected size").
SEQUENTIAL_CPU_COLLECTIVES = "--xla_cpu_enable_concurrency_optimized_scheduler=false"


def maybe_init_distributed() -> None:
    """``jax.distributed.initialize()`` when the multi-host environment variables are set
    (before JAX's backend starts: XLA_FLAGS is read then)."""
    if os.environ.get("JAX_COORDINATOR_ADDRESS") and os.environ.get("JAX_NUM_PROCESSES"):
        flags = os.environ.get("XLA_FLAGS", "")
        if "concurrency_optimized_scheduler" not in flags:
            os.environ["XLA_FLAGS"] = f"{flags} {SEQUENTIAL_CPU_COLLECTIVES}".strip()
        jax.distributed.initialize(
            coordinator_address=os.environ["JAX_COORDINATOR_ADDRESS"],
            num_processes=int(os.environ["JAX_NUM_PROCESSES"]),
            process_id=int(os.environ.get("JAX_PROCESS_ID", "0")))


def barrier(name: str, timeout_s: int = 3600) -> None:
    """Wait until every process gets here (several processes only). Gloo's CPU collectives give
    up after 30 s, so processes meet here before work whose duration differs between them
    (compiling, loading) is followed by a collective."""
    if jax.process_count() > 1:
        from jax._src import distributed  # private JAX API: only for several processes

        distributed.global_state.client.wait_at_barrier(f"igdrivsim-{name}", timeout_s * 1000)


def make_mesh() -> Mesh:
    """A 1-D mesh ``('data',)`` over all (global) devices: scenarios sharded, params replicated."""
    return Mesh(np.asarray(jax.devices()), ("data",))


def batch_sharding(mesh: Mesh) -> NamedSharding:
    """Arrays ``[S, B, ...]``: the scenario axis ``B`` split over the mesh."""
    return NamedSharding(mesh, PartitionSpec(None, "data"))


def replicated(mesh: Mesh) -> NamedSharding:
    return NamedSharding(mesh, PartitionSpec())


def place(tree, sharding: NamedSharding):
    """Host arrays -> global device arrays; every process holds the full host copy and hands
    over the pieces its local devices own (works for one and for several hosts). Typed PRNG
    keys travel as their raw data."""

    def one(x):
        if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            return jax.random.wrap_key_data(one(jax.random.key_data(x)),
                                            impl=jax.random.key_impl(x))
        x = np.asarray(x)
        return jax.make_array_from_callback(x.shape, sharding, lambda idx: x[idx])

    return jax.tree.map(one, tree)
