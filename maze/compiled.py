"""The maze study's compiled programs: :class:`Program` compiles a ``jit``ted function ahead
of time once per argument shapes (thread-safe, counted), and :class:`Study` holds every
program the study's stages call (PPO, BC, demonstrations, evaluation, the baselines), each
``vmap``ped over the rows (seeds) of a stage, so all curves and seed parts of one size share
one compilation; :meth:`Study.warm` compiles them all first, on the lanes.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from igdrivsim.lanes import Job, run_jobs
from maze import extended
from maze.bc import collect_demos, make_bc
from maze.dagger import make_dagger
from maze.env import make_params
from maze.mixed import make_mixed
from maze.network import init_stacked, make_policy, without_aux
from maze.ppo import make_ppo
from maze.rollout import evaluate


def use_compile_cache(folder) -> None:
    """Keep every compiled program in JAX's persistent compilation cache under ``folder`` (a
    later run with the same programs loads them instead of compiling; a cache named by
    ``JAX_COMPILATION_CACHE_DIR``, the pipeline's, is kept); set once per process, before the
    first compilation. On a CPU the cache holds no GPU autotuning folder, whose path would enter
    every entry's key: a copied or moved cache is found as well."""
    if not os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    if jax.default_backend() == "cpu":
        jax.config.update("jax_persistent_cache_enable_xla_caches", "none")


def _key(cfg, *path: int) -> jax.Array:
    """The PRNG key of ``path`` under the study's base seed ``cfg.seed``."""
    return extended.stage_key(cfg.seed, *path)


# XLA's backend optimisation level 1 on a CPU: the study's programs compile in about half the
# time (ppo_chunk 13.1 -> 9.4 s, evaluate 8.3 -> 3.1 s, collect 7.6 -> 3.2 s on one core) and
# run as fast (their time is the GRU's small products, which LLVM's costly passes do not speed
# up; docs/bench/README.md). Compiling was an eighth of a fresh study's CPU time.
CPU_COMPILER_OPTIONS = {"xla_backend_optimization_level": 1}


class Program:
    """A ``jit``ted function compiled ahead of time once per argument shapes, behind a lock:
    two lanes calling it at once compile it once, and the study counts what it compiled. On a
    CPU it is compiled with :data:`CPU_COMPILER_OPTIONS`."""

    def __init__(self, fn):
        self.jitted = jax.jit(fn)
        self.lock = threading.Lock()
        self.executables: dict = {}
        self.seconds = 0.0

    @staticmethod
    def signature(args) -> tuple:
        return (jax.tree.structure(args), tuple(
            (tuple(x.shape), str(x.dtype), bool(getattr(x, "weak_type", False)))
            for x in jax.tree.leaves(args)))

    def executable(self, *args):
        """The compiled program for ``args`` (arrays or ``jax.ShapeDtypeStruct``)."""
        key = self.signature(args)
        with self.lock:
            if key not in self.executables:
                t0 = time.perf_counter()
                options = CPU_COMPILER_OPTIONS if jax.default_backend() == "cpu" else {}
                self.executables[key] = self.jitted.lower(*args).compile(options)
                self.seconds += time.perf_counter() - t0
            return self.executables[key]

    def __call__(self, *args):
        return self.executable(*args)(*args)

    def shape(self, *args):
        """The output's shapes (``jax.eval_shape``), without compiling."""
        return jax.eval_shape(self.jitted, *args)


class Study:
    """Compiled functions shared by every stage (one compile each for all curves and seed parts
    of one size: :meth:`warm` compiles them all first, in parallel)."""

    def __init__(self, cfg):  # a maze.study.StudyConfig
        self.cfg = cfg
        self.params = make_params(cfg.size, cfg.receptive_field, cfg.max_steps)
        self.model = make_policy(cfg.hidden, self.params)
        ppo_init, ppo_chunk = make_ppo(self.model, self.params, cfg.ppo, cfg.chunk_updates)
        self.ppo_init = Program(jax.vmap(ppo_init))
        self.ppo_chunk = Program(jax.vmap(ppo_chunk))
        bc_init, bc_chunk = make_bc(self.model, cfg.bc, cfg.bc_chunk_epochs)
        self.bc_init = Program(jax.vmap(bc_init))
        self.bc_chunk = Program(jax.vmap(bc_chunk))
        self.collect = Program(jax.vmap(
            lambda p, k, e, i: collect_demos(self.model, p, k, cfg.bc, self.params, e, i)))
        self.evaluate = Program(jax.vmap(
            lambda p, k, partial: evaluate(self.model, p, k, cfg.eval_episodes, self.params,
                                           partial)))

        self._baselines = None

    def _build_baselines(self):
        """Compiled DAgger and BC+PPO/ADVISOR functions (built on first use)."""
        if self._baselines is None:
            cfg = self.cfg
            self.mixed_model = make_policy(cfg.hidden, self.params, aux_head=True)
            m_init, m_chunk = make_mixed(self.mixed_model, self.model, self.params, cfg.ppo,
                                         cfg.mixed, cfg.chunk_updates)
            d_init, d_iter = make_dagger(self.model, self.model, self.params, cfg.dagger)
            self._baselines = (Program(jax.vmap(m_init)), Program(jax.vmap(m_chunk)),
                               Program(jax.vmap(d_init)), Program(jax.vmap(d_iter)))
        return self._baselines

    mixed_init = property(lambda self: self._build_baselines()[0])
    mixed_chunk = property(lambda self: self._build_baselines()[1])
    dagger_init = property(lambda self: self._build_baselines()[2])
    dagger_iter = property(lambda self: self._build_baselines()[3])

    def programs(self) -> dict[str, Program]:
        names = ["ppo_init", "ppo_chunk", "bc_init", "bc_chunk", "collect", "evaluate"]
        if self._baselines is not None:
            names += ["mixed_init", "mixed_chunk", "dagger_init", "dagger_iter"]
        return {n: getattr(self, n) for n in names}

    def compiled(self) -> dict[str, int]:
        """Programs compiled so far, per function."""
        return {n: len(p.executables) for n, p in self.programs().items()}

    def compile_seconds(self) -> float:
        return sum(p.seconds for p in self.programs().values())

    def warm(self, rows: int, lanes: int) -> None:
        """Compile every program a stage of ``rows`` seeds calls, on ``lanes`` threads (the
        largest first), so that no stage waits for another's compilation."""
        cfg = self.cfg
        which = tuple(range(rows))
        net = self.init_params(0, cfg.seeds, which)
        keys = jnp.stack([_key(cfg, 0, j) for j in which])
        flags, totals = jnp.zeros(rows, bool), jnp.ones(rows, jnp.int32)
        demos = self.collect.shape(net, keys, flags, flags)
        tasks = [(self.ppo_chunk, (self.ppo_init.shape(keys, net, flags, totals),)),
                 (self.bc_chunk, (self.bc_init.shape(keys, net, demos),))]
        if cfg.baselines:
            mixed_net = self.init_mixed_params(0, cfg.seeds, which)
            tasks += [(self.mixed_chunk, (self.mixed_init.shape(keys, mixed_net, flags, totals),
                                          net)),
                      (self.dagger_iter, (self.dagger_init.shape(keys, net), net)),
                      (self.mixed_init, (keys, mixed_net, flags, totals)),
                      (self.dagger_init, (keys, net))]
        tasks += [(self.evaluate, (net, keys, flags)), (self.collect, (net, keys, flags, flags)),
                  (self.ppo_init, (keys, net, flags, totals)), (self.bc_init, (keys, net, demos))]
        run_jobs([Job(str(i), lambda _echo, p=p, a=a: p.executable(*a))
                  for i, (p, a) in enumerate(tasks)], lanes)

    @staticmethod
    def strip_aux(net_params):
        return without_aux(net_params)

    def init_params(self, curve: int, rows: int, which: Sequence[int] | None = None):
        """Initial parameters of ``rows`` seeds (only the seeds ``which``, when given)."""
        return init_stacked(self.model, _key(self.cfg, curve, 0), rows, self.params.obs_dim,
                            which)

    def init_mixed_params(self, curve: int, rows: int, which: Sequence[int] | None = None):
        self._build_baselines()
        return init_stacked(self.mixed_model, _key(self.cfg, curve, 0), rows,
                            self.params.obs_dim, which)

    def eval_rows(self, net_params, partial: bool, key: jax.Array, rounds: int = 1,
                  seeds: Sequence[int] | None = None):
        """Mean return and length per row (seed) over ``rounds * eval_episodes`` episodes;
        ``seeds``: the rows are these seeds of the study (the keys they have in the whole)."""
        rows = jax.tree.leaves(net_params)[0].shape[0]
        flags = jnp.full(rows, partial)

        def keys(r):
            split = jax.random.split(jax.random.fold_in(key, r),
                                     rows if seeds is None else self.cfg.seeds)
            return split if seeds is None else split[np.asarray(seeds)]

        out = [self.evaluate(net_params, keys(r), flags) for r in range(rounds)]
        ret = np.mean([np.asarray(o[0]) for o in out], axis=0)
        length = np.mean([np.asarray(o[1]) for o in out], axis=0)
        return ret, length
