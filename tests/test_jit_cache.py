"""Numba's on-disk cache: a second process runs the step loop without recompiling it."""

import contextlib
import os
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from softsim.integrators.symplectic_euler import update_from_forces

SCRIPT = textwrap.dedent("""
    import numpy as np
    from softsim.config import parse_scene
    from softsim.integrators.symplectic_euler import advance_colour
    from softsim.model import initial_state
    from softsim.simulation import prepare, step

    scene = parse_scene({
        "mesh": {"shape": "box", "size": [1, 1, 1], "element_size": 0.5, "structured": True},
        "material": {"model": "stvk", "youngs_modulus": 1e5, "poissons_ratio": 0.3, "density": 1000},
    })
    prepared = prepare(scene)
    state = initial_state(scene, prepared.model)
    step(prepared.model, state, prepared.plan.dt, 3, 0.0, np.empty((prepared.model.tet_count, 4, 3)))
    print(sum(advance_colour.stats.cache_hits.values()), sum(advance_colour.stats.cache_misses.values()))
""")


def _hits_and_misses():
    out = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, check=True).stdout
    hits, misses = map(int, out.split()[-2:])
    return hits, misses


def test_second_process_loads_the_step_loop_from_cache():
    _hits_and_misses()                      # compiles (or already cached by an earlier run)
    hits, misses = _hits_and_misses()
    assert (hits, misses) == (1, 0)


RUN_SCRIPT = textwrap.dedent("""
    import sys
    from softsim.config import parse_scene
    from softsim.simulation import prepare, simulate

    scene = parse_scene({
        "mesh": {"shape": "box", "size": [1, 0.2, 0.2], "element_size": 0.1, "structured": True},
        "material": {"model": "neohookean", "youngs_modulus": 1e5, "poissons_ratio": 0.3, "density": 1000},
        "fixed": [{"min": [-1, -1, -1], "max": [1e-6, 1, 1]}],
        "time": {"duration": 0.05}, "output": {"frame_interval": 0.01, "fields": ["von_mises", "energy"]},
    })
    prepared = prepare(scene)
    summary = simulate(prepared, sys.argv[1])
    print(summary.compile_time_s, summary.wall_time_s, summary.tet_steps_per_s,
          prepared.model.tet_count * prepared.plan.total_steps * prepared.substeps)
""")


def test_a_second_run_compiles_nothing(tmp_path):
    """The whole run, not only the step loop (the guard's, the energy's and the output fields'
    kernels too), comes from the cache in a second process, whose rate is then its tet-steps over
    the whole wall time."""
    def run(name):
        out = subprocess.run([sys.executable, "-c", RUN_SCRIPT, str(tmp_path / name)], capture_output=True,
                             text=True, check=True).stdout
        return [float(value) for value in out.split()[-4:]]

    run("first.h5")                             # compiles (or already cached by an earlier run)
    compiling, wall, rate, tet_steps = run("second.h5")
    assert compiling == 0.0
    assert rate == tet_steps / wall


def test_compile_timer_counts_compiling_not_calling():
    import numba

    from softsim.kernels.jit import compile_timer

    @numba.njit
    def twice(a):
        return 2.0 * a

    with compile_timer() as compiled:
        assert compiled() == 0.0
        twice(1.0)
        first = compiled()
        assert first > 0.0
        twice(2.0)
        assert compiled() == first
    twice(3)                                    # an int: compiled again, outside the timer
    assert compiled() == first


@contextlib.contextmanager
def one_millisecond():
    """A stand-in for ``kernels.jit.compile_timer`` that reports 1 ms of compiling."""
    yield lambda: 1e-3


def prepared_with_a_fixed_compile_time(monkeypatch):
    """A small prepared beam (two frames), ``simulate`` timing its compiling with ``one_millisecond``."""
    from softsim import simulation
    from softsim.config import parse_scene

    monkeypatch.setattr(simulation, "compile_timer", one_millisecond)
    return simulation.prepare(parse_scene({
        "mesh": {"shape": "box", "size": [1, 0.2, 0.2], "element_size": 0.1, "structured": True},
        "material": {"model": "stvk", "youngs_modulus": 1e5, "poissons_ratio": 0.3, "density": 1000},
        "time": {"duration": 0.02}, "output": {"frame_interval": 0.01}}))


def test_the_rate_leaves_out_what_compiling_took(tmp_path, monkeypatch):
    """``RunSummary.tet_steps_per_s`` is over the wall time less the compile time (here a fixed
    1 ms reported by a stand-in timer), which the summary gives apart."""
    from softsim import simulation

    prepared = prepared_with_a_fixed_compile_time(monkeypatch)
    summary = simulation.simulate(prepared, tmp_path / "run.h5")
    tet_steps = prepared.model.tet_count * prepared.plan.total_steps * prepared.substeps
    assert summary.compile_time_s == 1e-3 and summary.wall_time_s > 1e-3
    assert summary.tet_steps_per_s == tet_steps / (summary.wall_time_s - 1e-3)


def test_the_file_records_the_compile_time_and_the_sweep_rate_leaves_it_out(tmp_path, monkeypatch):
    """The run file's ``compile_time_s`` is the compile timer's (a stand-in reporting 1 ms a
    session), summed over the sessions of a stopped and resumed run; the sweep summary's
    ``tet_steps_per_s`` divides by the wall time less it, as ``RunSummary`` does."""
    import h5py

    from softsim import simulation
    from softsim.sweep.metrics import run_metrics

    prepared = prepared_with_a_fixed_compile_time(monkeypatch)
    path = tmp_path / "run.h5"
    first = simulation.simulate(prepared, path, should_stop=lambda: True)
    assert first.status == "interrupted"
    with h5py.File(path, "r") as f:
        assert f.attrs["compile_time_s"] == 1e-3
    simulation.simulate(prepared, path, resume=True)
    metrics = run_metrics(path)
    with h5py.File(path, "r") as f:
        assert f.attrs["status"] == "complete" and f.attrs["compile_time_s"] == 2e-3
        wall = float(f.attrs["wall_time_s"])
    assert metrics["compile_time_s"] == 2e-3
    assert metrics["tet_steps_per_s"] == prepared.model.tet_count * prepared.plan.total_steps / (wall - 2e-3)


ONE_MODEL_SCRIPT = textwrap.dedent("""
    import numpy as np
    from numba.core.errors import TypingError
    from softsim.kernels import blocked
    from softsim.kernels.jit import CompileTimeConstant
    from softsim.kernels.rest_state import rest_state
    from softsim.materials.models import MODEL_IDS
    from softsim.mesh.generate import structured_box

    points, tets = structured_box((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), 0.5)[:2]
    Dm_inv, V0 = rest_state(points, tets)
    model = MODEL_IDS["stvk"]
    layout = blocked.build_block_layout(tets, Dm_inv, V0, len(points), model=model)
    buf = np.zeros(blocked.SCRATCH_ROWS * blocked.BLOCK)
    loops = (blocked.stvk_block, blocked.neohookean_block, blocked.corotated_block, blocked.linear_block)
    blocked.model_forces(layout.rest[0], buf, CompileTimeConstant(model), 1.0, 1.0, None, None, np.uint8(4))
    print(*(len(loop.signatures) for loop in loops))
    try:
        blocked.model_forces(layout.rest[0], buf, model, 1.0, 1.0, None, None, np.uint8(4))
    except TypingError as exc:
        print("compile-time constant" in str(exc))
    # the per-frame kernels: the scene's law alone for a constant, every law for an int
    from softsim.kernels.energy import elastic_energy
    from softsim.kernels.forces import elastic_forces
    from softsim.kernels.rest_state import vertex_tet_csr
    from softsim.materials import models
    x = np.ascontiguousarray(points)
    elastic_energy(x, tets, Dm_inv, V0, CompileTimeConstant(model), 1.0, 1.0)
    elastic_forces(x, tets, Dm_inv, V0, CompileTimeConstant(model), 1.0, 1.0, *vertex_tet_csr(tets, len(points)))
    laws = (models.stvk_first_piola, models.stvk_energy_density, models.corotated_first_piola,
            models.corotated_energy_density)
    print(*(len(law.signatures) for law in laws))
    elastic_energy(x, tets, Dm_inv, V0, model, 1.0, 1.0)
    print(len(models.corotated_energy_density.signatures))
""")


def test_the_step_compiles_its_own_model_alone(tmp_path):
    """With the model id a ``CompileTimeConstant`` (as ``Model.material_id`` is), the lane loops of
    the other models are not compiled (all four in one function took a StVK scene's step 122 s to
    compile instead of 17), nor the other laws in the per-frame kernels; the step refuses a plain
    int at compile time, the per-frame kernels compile every law for it.  A fresh process and an
    empty cache, so that what is compiled shows in the functions' signatures."""
    out = subprocess.run([sys.executable, "-c", ONE_MODEL_SCRIPT], capture_output=True, text=True, check=True,
                         env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}).stdout.split()
    assert out[-10:] == ["1", "0", "0", "0", "True", "1", "1", "0", "0", "1"]


ONE_INDEX_TYPE_SCRIPT = textwrap.dedent("""
    import numpy as np
    from softsim.kernels import deformation, fields, forces, mat3, stiffness, tet_shape
    from softsim.kernels.jit import CompileTimeConstant
    from softsim.kernels.rest_state import rest_state, vertex_tet_csr
    from softsim.materials.models import MODEL_IDS
    from softsim.mesh.generate import structured_box
    points, tets = structured_box((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), 0.5)[:2]
    x = np.ascontiguousarray(points)
    Dm_inv, V0 = rest_state(points, tets)
    m, model = len(tets), CompileTimeConstant(MODEL_IDS["stvk"])
    tet_shape.tet_shapes(x, tets)
    stiffness.element_stiffness_maxima(x, tets, 1.0, 1.0)
    none = np.empty((0, 3, 3)), np.empty(0)
    fields.tet_fields_kernel(x, tets, Dm_inv, model, 1.0, 1.0, np.empty((m, 3, 3)), *none, *none, np.empty(m))
    corner = np.empty((m, 4, 3))
    forces.compute_tet_corner_forces(x, tets, Dm_inv, V0, model, 1.0, 1.0, corner)
    forces.gather_vertex_forces(corner, *vertex_tet_csr(tets, len(x)), np.empty_like(x))
    index_argument = {tet_shape.tet_shape: 2, deformation.edge_matrix: 2, mat3.mat3_load: 1,
                      forces.tet_corner_forces: 4, forces.gather_vertex_force: 3}
    for callee, k in index_argument.items():
        print(callee.__name__, *sorted({str(sig[k]) for sig in callee.signatures}), sep=",")
""")


def test_a_parallel_kernel_compiles_its_callees_for_one_index_type(tmp_path):
    """Numba types a ``prange`` body twice, the index an int64 and then, in the parallel loop, a
    uint64, so a jitted function called with the index compiled twice (tet_shapes with a cold
    cache 1.71-1.95 s, 1.25-1.29 s with one); the kernels pass it on as an int64
    (``kernels.jit.njit_parallel``).  A fresh process and an empty cache, so that what is compiled
    shows in the callees' signatures: their index argument has one type, int64."""
    out = subprocess.run([sys.executable, "-c", ONE_INDEX_TYPE_SCRIPT], capture_output=True, text=True, check=True,
                         env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}).stdout.split()
    assert out[-5:] == ["tet_shape,int64", "edge_matrix,int64", "mat3_load,int64", "tet_corner_forces,int64",
                        "gather_vertex_force,int64"]


ONE_REST_FORM_SCRIPT = textwrap.dedent("""
    import sys
    import numpy as np
    from softsim.kernels import blocked
    from softsim.kernels.element_checks import block_volume_ratios_and_stretches
    from softsim.kernels.jit import CompileTimeConstant
    from softsim.kernels.rest_state import rest_state
    from softsim.materials.models import MODEL_IDS
    from softsim.mesh.generate import structured_box
    points, tets = structured_box((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), 0.5)[:2]
    x, tets = np.ascontiguousarray(points), np.ascontiguousarray(tets, dtype=np.int64)
    Dm_inv, V0 = rest_state(x, tets)
    m = len(tets)
    for name in sys.argv[1:]:
        layout = blocked.build_block_layout(tets, Dm_inv, V0, len(x), model=MODEL_IDS[name])
        block_volume_ratios_and_stretches(x, layout.tets, layout.rest, CompileTimeConstant(layout.triangular), m,
                                          layout.whole_rows, np.empty(m), np.empty(m), np.ones(m), np.ones(m), 0.05)
        print(len(blocked.lane_rotated_deformation_gradient.signatures),
              len(blocked.lane_deformation_gradient.signatures))
""")


def test_the_guards_measure_compiles_the_lane_loop_of_its_rest_form_alone(tmp_path):
    """The guard's measure of the tets reads the rest data in the form the scene's law steps with
    (``kernels.rotated_rest``): that form, a ``CompileTimeConstant``, picks its lanes' deformation
    gradient at compile time, so a StVK scene compiles the triangular form's alone, and a linear one
    then adds the full form's (both were compiled in every run, about 0.5 s of a first run).  A fresh process and an
    empty cache, so that what is compiled shows in the loops' signatures."""
    out = subprocess.run([sys.executable, "-c", ONE_REST_FORM_SCRIPT, "stvk", "linear"], capture_output=True,
                         text=True, check=True, env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}).stdout.split()
    assert out[-4:] == ["1", "0", "1", "1"]


TWIN_SCRIPT = textwrap.dedent("""
    import sys
    from softsim.kernels import mat3
    F = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 10.0)
    if sys.argv[1] == "twin":
        mat3.mat3_mul(F, F)                 # the cached njit twin of mat3_mul_inline
    else:
        mat3.mat3_mul_inline(F, F)
        (sig,) = mat3.mat3_mul_inline.signatures
        print(sum(mat3.mat3_mul_inline.stats.cache_hits.values()),
              "alwaysinline" in mat3.mat3_mul_inline.inspect_llvm(sig))
""")


def test_an_always_inlined_helper_never_takes_its_cached_twins_code(tmp_path):
    """``jit.njit_inline``'s helpers carry LLVM's ``alwaysinline``, which the lane loops need to
    vectorise.  Numba keys its disk cache by Python function and signature, not by options, so a
    helper made from the same function as a cached ``njit`` one (``mat3_mul_inline`` of
    ``mat3_mul``) would load the twin's entry, compiled without the attribute: after the twin is
    cached in one process, the helper compiles its own code in the next."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    subprocess.run([sys.executable, "-c", TWIN_SCRIPT, "twin"], env=env, check=True)
    out = subprocess.run([sys.executable, "-c", TWIN_SCRIPT, "helper"], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    assert out[-2:] == ["0", "True"]


def _function_ir(dispatcher, sig):
    """The optimised LLVM IR of ``dispatcher``'s own function for ``sig`` (not its wrappers)."""
    name = dispatcher.overloads[sig].fndesc.mangled_name
    for body in re.split(r"(?m)^define ", dispatcher.inspect_llvm(sig))[1:]:
        if f"@{name}(" in body.split("\n", 1)[0]:
            return body
    raise AssertionError(f"no function {name} in the IR")


def _vertex_update_arguments(dtype, ground, damping):
    """Arguments of ``update_from_forces`` for 3 vertices in ``dtype``, as the step passes them (in
    float32: displacements from float64 rest positions; the ground's tuple and the damping in float64)."""
    n = 3
    held = np.zeros((n, 3), dtype=np.bool_)
    held[0] = True
    real = np.dtype(dtype).type
    return (np.zeros((n, 3), dtype), np.zeros((n, 3)) if dtype == np.float32 else None, np.ones((n, 3), dtype),
            np.ones((n, 4), dtype), 1, real(1e-3), real(1e-3), np.ones(n, dtype), tuple(map(real, (0.0, 0.0, -9.81))),
            None, held, np.zeros((n, 3), dtype), np.zeros((n, 3), dtype),
            (0.0, 1e6, 0.3, np.zeros(n)) if ground else None, damping)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("ground, damping", [(False, None), (True, None), (True, 0.99)])
def test_the_vertex_update_takes_and_releases_no_reference(ground, damping, dtype):
    """The step's per-vertex update is inlined by LLVM (``jit.njit_inline``) after Numba pruned its
    reference counting: every take or release of a reference to an array it is passed left in
    its IR would run per vertex as an atomic operation.  Written with the ground contact as a
    helper taking the arrays (an early return when above the ground), 16 were left, and the beam
    with a ground stepped at half the rate of the bare beam."""
    args = _vertex_update_arguments(dtype, ground, damping)
    update_from_forces(*args)
    sig = tuple(update_from_forces.typeof_pyval(a) for a in args)
    body = _function_ir(update_from_forces, sig)
    assert "@NRT_incref(" not in body and "@NRT_decref(" not in body


class FakeCacheFile:
    """The parts of Numba's ``IndexDataCacheFile`` that ``jit._save_data_first`` uses, in a folder,
    logging the order of the writes; ``fail_index``: writing the index raises (a process stopped
    between the two writes)."""

    def __init__(self, folder, fail_index=False):
        self._cache_path = str(folder)
        self.index = {}
        self.data = {}
        self.writes = []
        self.fail_index = fail_index

    def _load_index(self):
        return dict(self.index)

    def _data_name(self, number):
        return f"f.{number}.nbc"

    def _save_data(self, name, data):
        self.writes.append(("data", name))
        self.data[name] = data

    def _save_index(self, overloads):
        if self.fail_index:
            raise KeyboardInterrupt
        self.writes.append(("index", dict(overloads)))
        self.index = dict(overloads)


def test_a_cache_entry_is_written_data_first_and_a_stop_in_between_leaves_no_index_naming_it(tmp_path):
    from softsim.kernels.jit import _save_data_first

    cache_file = FakeCacheFile(tmp_path)
    cache_file.data["f.1.nbc"] = "stale code of an older source"
    _save_data_first(cache_file, "key a", "code a")
    assert cache_file.writes == [("data", "f.1.nbc"), ("index", {"key a": "f.1.nbc"})]
    stopped = FakeCacheFile(tmp_path, fail_index=True)
    with pytest.raises(KeyboardInterrupt):
        _save_data_first(stopped, "key b", "code b")
    assert stopped.index == {}                  # the key names no file: the next run compiles it


def test_a_cache_entry_waits_for_the_cache_folders_lock(tmp_path):
    """Written under the folder's exclusive lock: while another holds it, the write waits."""
    import threading

    fcntl = pytest.importorskip("fcntl")
    from softsim.kernels.jit import CACHE_LOCK_NAME, _save_data_first

    cache_file = FakeCacheFile(tmp_path)
    with open(tmp_path / CACHE_LOCK_NAME, "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        writer = threading.Thread(target=_save_data_first, args=(cache_file, "key", "code"))
        writer.start()
        writer.join(0.3)
        assert writer.is_alive() and cache_file.writes == []
    writer.join(5.0)
    assert not writer.is_alive() and cache_file.index == {"key": "f.1.nbc"}


def test_softsims_cached_kernels_read_and_write_their_entries_under_the_lock():
    from softsim.kernels import jit
    from softsim.kernels.energy import kinetic_energy

    cache_file = kinetic_energy._cache._cache_file
    assert cache_file.save.func is jit._save_data_first and cache_file.load.func is jit._load_locked
