"""A persistent cache of compiled XLA programs, for the CLI and the notebooks.

Compiling a trainer's update or an evaluation takes tens of seconds on a CPU;
with the cache on, a resumed or repeated run loads the programs instead.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax


def enable_compilation_cache() -> None:
    """Keep compiled XLA programs in ``$XDG_CACHE_HOME/jaxround/xla`` so that a
    resumed or repeated run skips the compilation; a cache folder set already
    (``JAX_COMPILATION_CACHE_DIR``) is left alone."""
    if jax.config.jax_compilation_cache_dir:
        return
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    jax.config.update("jax_compilation_cache_dir", str(cache / "jaxround" / "xla"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


__all__ = ["enable_compilation_cache"]
