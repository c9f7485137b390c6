"""The sweep: every prediction of a set on every source, a few sources at a time, in
this process or on an executor (worker processes, a Dask cluster), as a stream of
:class:`~cevm.core.sweep.block.SweepBlock`."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING

from cevm.core.sweep.block import DEFAULT_RESERVE_PCT, DEFAULT_SOC_START_PCT, SweepBlock
from cevm.core.sweep.evaluate import as_blocks, finish_blocks, predict_arrays, predict_sources
from cevm.core.sweep.predictions import PredictionSet
from cevm.core.sweep.sources import Source
from cevm.errors import CevmError

if TYPE_CHECKING:  # the executors (multiprocessing, concurrent.futures) are imported by a parallel sweep only
    from cevm.executors import Executor, Task


def _portable(source: Source, lowest_soc: bool) -> Source:
    """What a worker needs of ``source``: its vector, and its step terms when the lowest
    state of charge is asked for (the legs' profiles, and any store access behind them,
    stay here)."""
    out = Source(source.name, source.kind, source.vector, legs=(), block_elements=source.block_elements,
                 ambient_c=source.ambient_c, leg_vectors=source.leg_vectors, leg_ambient_c=source.leg_ambient_c)
    if lowest_soc:
        out.__dict__["steps"] = source.steps  # the cached_property's slot: set, not recomputed
    return out


#: Sources evaluated together by :func:`sweep`: as many as keep about this many
#: (EV prediction x block) cells in one evaluation (512 kB per work array; measured
#: with benchmarks/bench_sweep.py: 2x smaller or larger batches were 10-50 % slower).
SWEEP_BATCH_CELLS = 1 << 16


def _batches(sources: Sequence[Source], pset: PredictionSet, lowest_soc: bool) -> Iterator[tuple[int, int]]:
    """The (start, stop) source ranges :func:`sweep` evaluates together, in order."""
    n_rows = max(1, int(pset.is_ev.sum()) if lowest_soc else pset.n)
    use_steps = lowest_soc and bool(pset.is_ev.any())
    i = 0
    while i < len(sources):
        cells = 0
        j = i
        while j < len(sources) and (j == i or cells < SWEEP_BATCH_CELLS):
            cells += n_rows * (sources[j].steps.n_blocks if use_steps else 1)
            j += 1
        yield i, j
        i = j


def sweep(
    sources: Sequence[Source],
    pset: PredictionSet,
    *,
    soc_start_pct: float = DEFAULT_SOC_START_PCT,
    reserve_pct: float = DEFAULT_RESERVE_PCT,
    lowest_soc: bool = True,
    executor: Executor | None = None,
    ranges: bool = False,
) -> Iterator[SweepBlock]:
    """Every prediction of ``pset`` on every source: one block of ``pset.n`` rows per
    source, source-major (then vehicle, then mass), computed when asked for, a few
    sources at a time (:data:`SWEEP_BATCH_CELLS`).

    ``executor`` (:func:`cevm.executors.make_executor`: worker processes or a Dask
    cluster) evaluates the batches in parallel: each task gets a batch's vectors and
    step terms (built here, with any profile reading) and the set, and returns the
    arrays; blocks still come in source order, and equal a serial sweep's bit for bit
    (the batches are the same). Raises :class:`CevmError` if a task fails."""
    if executor is None or executor.inline:
        for i, j in _batches(sources, pset, lowest_soc):
            yield from predict_sources(sources[i:j], pset, soc_start_pct=soc_start_pct, reserve_pct=reserve_pct,
                                       lowest_soc=lowest_soc, first_index=i, ranges=ranges)
        return
    from cevm.executors import Task  # only with an executor: the process pools' modules stay unloaded otherwise

    use_steps = lowest_soc and bool(pset.is_ev.any())
    spans: list[tuple[int, int]] = []

    def tasks() -> Iterator[Task]:
        for i, j in _batches(sources, pset, lowest_soc):
            spans.append((i, j))
            batch = tuple(_portable(src, use_steps) for src in sources[i:j])
            yield Task(f"sources {i + 1}-{j} ({sources[i].name})",
                       (batch, pset, soc_start_pct, reserve_pct, lowest_soc))

    for k, res in enumerate(executor.run(predict_arrays, tasks())):
        i, j = spans[k]
        if not res.ok:
            raise CevmError(f"predictions for sources {i + 1}-{j} failed on a worker: {res.error}")
        yield from finish_blocks(as_blocks(sources[i:j], pset, res.value, i), soc_start_pct, reserve_pct, ranges)

