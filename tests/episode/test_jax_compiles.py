"""The JAX side of the closed loop compiles once: not again between control steps, nor for a second
chunk of the same shape (issue 5, item 3). Compilations are counted with ``jax.monitoring``."""

from __future__ import annotations

import jax
import jax.monitoring as monitoring

from benchmarks.solver import stub_planner
from mcverify.campaign.spec import campaign_from_dict
from mcverify.episode.rollout import run_episodes
from mcverify.sim import plant

COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"
TRACE_EVENT = "/jax/core/compile/jaxpr_trace_duration"
SEED = 11


class CompileLog:
    """Counts XLA compilations and jaxpr traces while active."""

    def __init__(self) -> None:
        self.compiles = 0
        self.traces = 0

    def _listener(self, event: str, duration_secs: float, **kwargs) -> None:
        self.compiles += event == COMPILE_EVENT
        self.traces += event == TRACE_EVENT

    def __enter__(self) -> CompileLog:
        monitoring.register_event_duration_secs_listener(self._listener)
        return self

    def __exit__(self, *exc) -> None:
        monitoring.unregister_event_duration_listener(self._listener)


def cells(front_speeds_kmh=(25, 36)):
    """Noisy 50 Hz cells of 0.3 s episodes (15 control steps), one per front-vehicle speed."""
    raw = {
        "campaign": {"name": "compiles", "seed": SEED, "episodes": 4},
        "model": {"sim": {"max_time_s": 0.3}, "noise": {"kind": "paper"}},
        "grid": {"scenario.front_speed_kmh": list(front_speeds_kmh)},
    }
    return campaign_from_dict(raw).cells


def test_counter_sees_compilations():
    """Control: with the caches emptied (other tests may have run the plant), the first chunk
    compiles, and the log counts it."""
    cell = cells()[0]
    jax.clear_caches()
    plant.compiled.cache_clear()
    with CompileLog() as log:
        run_episodes(cell, [0, 1, 2], SEED, stub_planner(cell.params))
    assert log.compiles > 0 and log.traces > 0


def test_no_compilation_between_control_steps():
    cell = cells()[0]
    per_step: list[tuple[int, int]] = []
    with CompileLog() as log:
        run_episodes(cell, [0, 1, 2, 3, 4], SEED, stub_planner(cell.params),
                     on_step=lambda step: per_step.append((log.compiles, log.traces)))
    assert len(per_step) == 15
    assert per_step[-1] == per_step[0]  # whatever compiled did so during the first step


def test_no_compilation_for_a_second_chunk_of_equal_shape():
    cell = cells()[0]
    stub = stub_planner(cell.params)
    run_episodes(cell, [0, 1], SEED, stub)
    with CompileLog() as log:
        rows = run_episodes(cell, [2, 3], SEED, stub).rows
    assert len(rows) == 2
    assert (log.compiles, log.traces) == (0, 0)


def test_no_compilation_for_a_chunk_of_another_cell_of_equal_shape():
    """Plant parameters are traced arguments: another cell (other front speed) reuses the compiled code."""
    a, b = cells()
    run_episodes(a, [0, 1], SEED, stub_planner(a.params))
    with CompileLog() as log:
        run_episodes(b, [0, 1], SEED, stub_planner(b.params))
    assert log.compiles == 0
