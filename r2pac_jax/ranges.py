"""Range checks of configuration values, shared by the generic config and each algorithm's own
checks (it sits below both, with `errors.ConfigError`)."""
from __future__ import annotations

from r2pac_jax.errors import ConfigError


def check_range(name: str, value, low=None, high=None, low_open=False, high_open=False) -> None:
    """Raise ConfigError unless low <= value <= high (open ends exclude the bound); arrays too."""
    import numpy as np

    v = np.asarray(value, dtype=float)
    ok = np.isfinite(v)
    if low is not None:
        ok &= (v > low) if low_open else (v >= low)
    if high is not None:
        ok &= (v < high) if high_open else (v <= high)
    if not np.all(ok):
        lo = "" if low is None else ("(" if low_open else "[") + f"{low}"
        hi = "" if high is None else f"{high}" + (")" if high_open else "]")
        where = (f"lie in {lo}, {hi}" if low is not None and high is not None
                 else f"be {'>' if low_open else '>='} {low}" if low is not None
                 else f"be {'<' if high_open else '<='} {high}")
        raise ConfigError(f"{name} must {where}, got {value}")
