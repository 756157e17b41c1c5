"""What a run was computed on, as far as it decides the floats of its result.

The same seed, frames and settings give bitwise the same poses only where the compiled
program and the way it runs are the same. Three things on the machine decide that:

* jax / jaxlib (the compiler) and the backend (its device kind);
* the CPU, whose instruction set and caches XLA's code and its matrix products are tuned for.
  Its model name alone does not tell: a virtual machine may report only "AMD EPYC" for
  processors of several generations, and XLA compiles for what the host offers (on one with
  AVX-512 it vectorises the same loops otherwise, and sums in another order). So the record
  keeps the processor's family, model and vector extensions too (:func:`instruction_set`);
* the number of cores the process may use: XLA's matrix products (the 7x7 normal equations
  of every Gauss-Newton step, a sum over all pixels) split that sum across XLA's threads,
  one per usable core, so another core count adds the pixels in another order. The pose then
  differs at float rounding, and the robust steps of a tracked crowd can grow that to
  millimetres of ATE (docs/decisions/machine-record.md).

:func:`record` collects them; ``jaxvo run`` writes it into its trajectory header
(``# machine: {...}``), and ``jaxvo run --config TRAJ`` names what differs (:func:`differences`)
before it reruns a trajectory made elsewhere.
"""
from __future__ import annotations

import os
import platform
from pathlib import Path
from typing import Dict, List, Mapping, Optional

__all__ = ["record", "differences", "cpu_model", "instruction_set", "usable_cores"]


def cpu_model() -> str:
    """The CPU's model name (Linux ``/proc/cpuinfo``; else :func:`platform.processor`)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


# the /proc/cpuinfo flags that change the code LLVM emits for XLA's loops: the vector and
# fused-multiply-add extensions (a prefix matches e.g. every avx512* and amx* flag)
_VECTOR_FLAGS = ("sse4", "avx", "fma", "f16c", "amx", "asimd", "sve")


def instruction_set(cpuinfo: Optional[str] = None) -> str:
    """The processor's generation and vector extensions, as XLA's code depends on them:
    ``"<machine> family F model M: flag flag ..."`` (Linux ``/proc/cpuinfo``, or the text
    ``cpuinfo`` in its format: cpu family, model and the SSE4 / AVX / FMA / F16C / AMX (x86) or
    ASIMD / SVE (Arm) flags, sorted); elsewhere :func:`platform.machine` alone."""
    arch = platform.machine() or "unknown"
    text = cpuinfo
    if text is None:
        try:
            text = Path("/proc/cpuinfo").read_text()
        except OSError:
            return arch
    fields = {}
    for line in text.splitlines():
        if not line.strip():
            break                                   # the first processor's block is enough
        name, _, value = line.partition(":")
        fields.setdefault(name.strip().lower(), value.strip())
    flags = (fields.get("flags") or fields.get("features") or "").split()
    vector = sorted({f for f in flags if f.startswith(_VECTOR_FLAGS)})
    family, model = fields.get("cpu family"), fields.get("model")
    where = f" family {family} model {model}" if family and model else ""
    return f"{arch}{where}: {' '.join(vector)}"


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS has one, e.g. under ``taskset``)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def record() -> Dict[str, object]:
    """{"cpu", "isa", "cores", "jax", "jaxlib", "device"}: what decides a run's floats on this
    machine (see the module docstring); "isa" is :func:`instruction_set`, "device" the default
    backend's platform and device kind."""
    import jax
    import jaxlib

    dev = jax.devices()[0]
    return {"cpu": cpu_model(), "isa": instruction_set(), "cores": usable_cores(), "jax": jax.__version__, "jaxlib": jaxlib.__version__,
            "device": f"{dev.platform} ({dev.device_kind})"}


def differences(recorded: Mapping, current: Mapping) -> List[str]:
    """``"name: recorded -> current"`` for each field of ``recorded`` that ``current`` has
    otherwise (fields only one of them has are left out: an older or newer header)."""
    out = []
    for name, value in recorded.items():
        if name in current and current[name] != value:
            out.append(f"{name}: {value} -> {current[name]}")
    return out
