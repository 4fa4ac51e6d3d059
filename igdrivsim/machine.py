"""Where and when a measurement ran: the ``machine`` record every ``igdrivsim bench --out`` file
carries, so a speed cited in the docs names its machine, date and load."""

from __future__ import annotations

import datetime as _dt
import os
import platform
import sys


def machine_record() -> dict:
    """CPU count, load average, OS, Python, JAX, its devices and default matrix precision, date
    (UTC) and command line."""
    import jax  # lazy: JAX only when a record is taken

    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:  # not available on this platform
        load = None
    return {"date": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
            "cpus": os.cpu_count(), "load_average_1_5_15_min": load,
            "platform": platform.platform(), "processor": platform.processor() or None,
            "python": platform.python_version(), "jax": jax.__version__,
            "backend": jax.default_backend(),
            "devices": sorted({d.device_kind for d in jax.devices()}),
            # JAX_DEFAULT_MATMUL_PRECISION changes what a float32 product costs on a GPU
            "matmul_precision": jax.config.jax_default_matmul_precision,
            "command": " ".join(["igdrivsim", *sys.argv[1:]]) if sys.argv else None}
