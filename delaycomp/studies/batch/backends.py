"""The array libraries of the batch engines: numpy, CuPy or JAX behind one ``Backend``
(its namespace, the conversions to and from the host, an in-place update that JAX's
immutable arrays do by copy), chosen and checked by ``get_backend``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from delaycomp.studies.batch.base import BatchError

#: Array libraries ``get_backend`` knows; ``auto`` takes the first GPU library found.
BACKENDS = ("numpy", "cupy", "jax", "auto")


@dataclass(frozen=True)
class Backend:
    """An array library with numpy's API: its namespace, conversions, in-place update."""

    name: str
    #: the array module (``numpy``, ``cupy`` or ``jax.numpy``): ``Any``, as the three share
    #: numpy's API but no common static type
    xp: Any
    device: str

    def asarray(self, a):
        """``a`` as an array of this library (on its device)."""
        return self.xp.asarray(a)

    def to_numpy(self, a) -> np.ndarray:
        """``a`` (an array of this library) as a numpy array on the host."""
        if self.name == "cupy":
            return self.xp.asnumpy(a)
        return np.asarray(a)

    def put(self, a, index, value):
        """``a[index] = value``, returning the array (JAX arrays are immutable)."""
        if self.name == "jax":
            return a.at[index].set(value)
        a[index] = value
        return a


def get_backend(name: str = "numpy") -> Backend:
    """The array library ``name`` (one of ``BACKENDS``), checked to be usable.

    ``jax`` runs in double precision (``jax_enable_x64`` is switched on: the maths needs
    float64). ``auto`` is CuPy if it sees a GPU, else JAX if it sees one, else numpy.
    Raises ``BatchError`` naming what is missing.
    """
    if name not in BACKENDS:
        raise BatchError(f"array backend {name!r} is not allowed: must be one of "
                         f"{', '.join(BACKENDS)}")
    if name == "numpy":
        return Backend("numpy", np, "cpu")
    if name == "auto":
        for candidate in ("cupy", "jax"):
            try:
                backend = get_backend(candidate)
            except BatchError:
                continue
            if backend.device != "cpu":
                return backend
        return Backend("numpy", np, "cpu")
    if name == "cupy":
        try:
            import cupy
        except ImportError:
            raise BatchError("array backend cupy is not installed: pip install "
                             "'delaycomp[cupy]' (CUDA 12; needs an NVIDIA GPU)") from None
        try:
            count = cupy.cuda.runtime.getDeviceCount()
        except Exception as exc:  # noqa: BLE001 - no driver, no device: say so in one line
            raise BatchError(f"array backend cupy cannot reach a GPU: {exc}") from None
        if count < 1:
            raise BatchError("array backend cupy cannot reach a GPU: no device")
        props = cupy.cuda.runtime.getDeviceProperties(0)
        label = props["name"].decode() if isinstance(props["name"], bytes) else props["name"]
        return Backend("cupy", cupy, f"gpu ({label})")
    try:
        import jax
    except ImportError:
        raise BatchError("array backend jax is not installed: pip install "
                         "'delaycomp[jax]'") from None
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    dev = jax.devices()[0]
    return Backend("jax", jnp, "cpu" if dev.platform == "cpu" else f"{dev.platform} ({dev})")
