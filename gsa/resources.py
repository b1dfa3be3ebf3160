"""What a study will need in memory and on disk, known before it starts.

A Sobol' run keeps its whole design and all its outputs in memory (the
analysis needs every block of Y at once) and writes the outputs to disk as
chunks. Both grow as N (G + 2) (k + M): the paper's SAM study at N = 2^20 is
~90 GB of outputs. :func:`check` turns "ArrayMemoryError after minutes" into
one message up front with the largest N that fits.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from gsa.bootstrap import DEFAULT_MEMORY_BUDGET
from gsa.errors import GSAError

_F8 = 8  # bytes per float64
#: bytes beyond the arrays counted below: the interpreter with numpy, scipy, numba and
#: matplotlib loaded, and the figures. Measured peak RSS of paper_parameters: 0.36 GB at N = 256
#: (estimate 0.83 GB), 0.88 GB at N = 4096 (estimate 1.5 GB): cautious at small N, where nothing
#: is refused anyway; at large N the outputs and the design dominate and are counted exactly.
BASE_BYTES = 512 * 2**20
#: copies of one chunk's outputs alive at once (the model's result, the copy the
#: background writer saves, numpy's .npz buffer)
CHUNK_COPIES = 3


@dataclass(frozen=True)
class Needs:
    """Bytes a run needs: in memory at its peak, and on disk for its chunks."""

    memory: int
    disk: int


def needs(N: int, k: int, G: int, M: int, chunk_size: int, with_BA: bool = False) -> Needs:
    """Peak memory and chunk disk space [bytes] of a study with base sample size ``N``,
    ``k`` parameters in ``G`` factors, ``M`` outputs, run in chunks of ``chunk_size`` runs."""
    n_runs = N * (2 * G + 2 if with_BA else G + 2)
    design = _F8 * (2 * N * 2 * k + 2 * n_runs * k)  # the Sobol' points, A and B; U and X
    outputs = _F8 * n_runs * M
    chunk = _F8 * min(chunk_size, n_runs) * M * CHUNK_COPIES
    return Needs(memory=BASE_BYTES + design + outputs + chunk + DEFAULT_MEMORY_BUDGET, disk=outputs)


def available_memory() -> int | None:
    """Bytes the system can give a new process without swapping (Linux: MemAvailable), or None."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def free_disk(folder: Path) -> int:
    """Free bytes on the file system that holds ``folder`` (or its nearest existing parent)."""
    folder = Path(folder).absolute()
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    return shutil.disk_usage(folder).free


def check(N: int, k: int, G: int, M: int, chunk_size: int, out: Path, *, with_BA: bool = False,
          reusable_bytes: int = 0) -> Needs:
    """GSAError saying what fits when a study with base sample size ``N`` would not fit in
    the available memory, or its chunks not on the disk of ``out`` (``reusable_bytes``: chunks
    already there, of a run being resumed)."""
    need = needs(N, k, G, M, chunk_size, with_BA)
    memory = available_memory()
    if memory is not None and need.memory > memory:
        fits = _largest_power_of_two(lambda n: needs(n, k, G, M, chunk_size, with_BA).memory <= memory)
        raise GSAError(
            f"N = {N}: the study needs about {_gib(need.memory)} of memory ({_runs(N, G, with_BA)} runs x {M} "
            f"outputs in float64, with the design) but {_gib(memory)} is available; {_what_fits(fits)}"
        )
    disk = free_disk(out) + reusable_bytes
    if need.disk > disk:
        fits = _largest_power_of_two(lambda n: needs(n, k, G, M, chunk_size, with_BA).disk <= disk)
        raise GSAError(
            f"N = {N}: the study's chunks need about {_gib(need.disk)} on disk but {out} has "
            f"{_gib(disk)} free; {_what_fits(fits)}, or choose a folder on a larger disk"
        )
    return need


def _largest_power_of_two(fits) -> int:
    n = 2
    while fits(2 * n):
        n *= 2
    return n if fits(n) else 0


def _what_fits(N: int) -> str:
    return f"N = {N} fits (the largest power of two that does)" if N else "not even N = 2 fits"


def _runs(N: int, G: int, with_BA: bool) -> int:
    return N * (2 * G + 2 if with_BA else G + 2)


def _gib(n: int) -> str:
    return f"{n / 2**30:.1f} GiB"
