"""Which machine a logged run ran on, and when two logged runs ran on the same one.

A cold benchmark's time and a perf ratio are figures of the machine as much as of the code
(issue 30: the same code's tap loop gained 3.5-5.3x per tap over its scalar loop on a 2-core
AVX-512 EPYC and 1.9-2.6x on a 2-core first-generation EPYC with AVX2 only), so the logs of
both (experiments/cold_runs.jsonl, experiments/perf_runs.jsonl) record it with each run
(:func:`run_machine`) and pool only the runs of one machine (:func:`machine_key`).
"""

from __future__ import annotations

from typing import Any


def cpu_generation(text: str | None = None) -> str | None:
    """``"family/model"`` of the first CPU in ``/proc/cpuinfo``
    (:func:`experiments.readme_timings.cpuinfo`; ``text``: its content, read when ``None``),
    e.g. ``"23/1"`` for a first-generation AMD EPYC: a virtual machine may name its CPU only
    ``"AMD EPYC"``, whatever its generation. ``None`` where not found."""
    from experiments.readme_timings import cpuinfo

    fields = cpuinfo(text)
    if "cpu family" not in fields or "model" not in fields:
        return None
    return f"{fields['cpu family']}/{fields['model']}"


def run_machine() -> dict[str, object]:
    """The machine a logged run ran on: :func:`experiments.readme_timings.machine`, the CPU's
    family and model (:func:`cpu_generation`) and the native tap loop's SIMD level (``None``
    without the library)."""
    from experiments.readme_timings import machine
    from sssbench.ops import native

    return {**machine(), "cpu_model": cpu_generation(), "simd": native.simd_level()}


#: what makes two logged runs' machines the same for pooling (:func:`machine_key`): the
#: CPU's model name, its family and model numbers, its core count and the tap loop's SIMD
#: level (the Python and the system are recorded, not compared)
MACHINE_KEYS = ("cpu", "cpu_model", "cores", "simd")

#: ``machine=`` of the log's readers: records of every machine
ANY_MACHINE: Any = object()


def machine_key(machine: object) -> tuple | None:
    """The pooling key of a record's ``machine`` (:func:`run_machine`): its
    :data:`MACHINE_KEYS` values; ``None`` for a record without one (logged before machines
    were: cold runs until 2026-12-04, perf runs until 2026-12-05; such runs pool only with
    each other)."""
    if not isinstance(machine, dict):
        return None
    return tuple(str(machine.get(k)) for k in MACHINE_KEYS)


def machine_words(machine: object) -> str:
    """``"AMD EPYC (family/model 23/1), 2 cores, SIMD level avx2"``: a record's machine
    (:data:`MACHINE_KEYS`) in words; ``"a machine not recorded"`` for a record without
    one."""
    if not isinstance(machine, dict):
        return "a machine not recorded"
    gen = machine.get("cpu_model")
    cpu = f"{machine.get('cpu')}" + (f" (family/model {gen})" if gen else "")
    return f"{cpu}, {machine.get('cores')} cores, SIMD level {machine.get('simd')}"


def on_machine(record: dict, machine: object) -> bool:
    """Whether a logged ``record`` (a cold run's or a perf run's) ran on ``machine`` (a
    :func:`run_machine` dict, compared by :func:`machine_key`; ``None``: the records logged
    without a machine; :data:`ANY_MACHINE`: every machine): the one pooling rule of both logs."""
    return machine is ANY_MACHINE or machine_key(record.get("machine")) == machine_key(machine)
